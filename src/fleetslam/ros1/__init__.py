"""ROS 1 without ROS: the master's XML-RPC API and TCPROS in the standard library, messages via rosbags' Noetic store.

Used by ``fleetslam bridge ros1``; nothing here imports rospy or any ROS 1 package. Names are loaded on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.ros1.bag import BagConversion, convert_to_rosbag1
    from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
    from fleetslam.ros1.messages import ros1_typestore
    from fleetslam.ros1.node import MasterUnreachableError, Ros1Node, Ros1Publisher, Ros1ServiceServer, Ros1Subscription
    from fleetslam.ros1.rviz import rviz_config

__all__ = [
    "BagConversion",
    "MasterUnreachableError",
    "Ros1Bridge",
    "Ros1Node",
    "Ros1Publisher",
    "Ros1ServiceServer",
    "Ros1Subscription",
    "TopicRule",
    "convert_to_rosbag1",
    "ros1_typestore",
    "rviz_config",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "bridge": ["Ros1Bridge", "TopicRule"],
            "node": ["MasterUnreachableError", "Ros1Node", "Ros1Publisher", "Ros1ServiceServer", "Ros1Subscription"],
            "messages": ["ros1_typestore"],
            "bag": ["BagConversion", "convert_to_rosbag1"],
            "rviz": ["rviz_config"],
        },
    )
