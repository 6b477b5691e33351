"""fleetslam's middleware: ROS 2 messages over Zenoh, wire-compatible with rmw_zenoh.

See ``docs/middleware-api.md``. Only node modules, the station, the launcher and the CLI import this package.

Threading in one sentence: each :class:`Node` has one executor thread that runs all of its callbacks
(subscriptions, services, timers) one at a time in arrival order; publishing and service calls are thread-safe.
"""

from fleetslam.middleware.context import Context
from fleetslam.middleware.graph import EndpointInfo, Graph, NodeInfo
from fleetslam.middleware.node import Client, MessageInfo, Node, Publisher, Service, Subscription, Timer
from fleetslam.middleware.router import Router
from fleetslam.middleware.wire import QoSProfile

__all__ = [
    "Client",
    "Context",
    "EndpointInfo",
    "Graph",
    "MessageInfo",
    "Node",
    "NodeInfo",
    "Publisher",
    "QoSProfile",
    "Router",
    "Service",
    "Subscription",
    "Timer",
]
