"""fleetslam's middleware: ROS 2 messages over Zenoh, wire-compatible with rmw_zenoh.

See ``docs/middleware-api.md``. Only node modules, the station, the launcher and the CLI import this package.
"""

from fleetslam.middleware.context import Context
from fleetslam.middleware.node import Client, MessageInfo, Node, Publisher, Service, Subscription, Timer
from fleetslam.middleware.router import Router
from fleetslam.middleware.wire import QoSProfile

__all__ = [
    "Client",
    "Context",
    "MessageInfo",
    "Node",
    "Publisher",
    "QoSProfile",
    "Router",
    "Service",
    "Subscription",
    "Timer",
]
