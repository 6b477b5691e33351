"""The simulated inspection plant (MuJoCo): procedural hall, diff-drive robots, Kinect-like RGB-D, TUM export,
and the simulator node.

Names are loaded on first use: ``import fleetslam.sim`` imports no submodule, and MuJoCo and OpenCV (the ``sim``
extra) are imported only when a name that needs them is used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.sim.camera import CameraIntrinsics, KinectModel
    from fleetslam.sim.config import CameraConfig, RobotPlacement, SimConfig, WorldConfig
    from fleetslam.sim.export import ExportResult, export_tum
    from fleetslam.sim.node import SimNode, run_sim_node
    from fleetslam.sim.plant import Plant, SimRobot
    from fleetslam.sim.world import build_world, world_xml

__all__ = [
    "CameraConfig",
    "CameraIntrinsics",
    "ExportResult",
    "KinectModel",
    "Plant",
    "RobotPlacement",
    "SimConfig",
    "SimNode",
    "SimRobot",
    "WorldConfig",
    "build_world",
    "export_tum",
    "run_sim_node",
    "world_xml",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "config": ["CameraConfig", "RobotPlacement", "SimConfig", "WorldConfig"],
            "plant": ["Plant", "SimRobot"],
            "camera": ["CameraIntrinsics", "KinectModel"],
            "world": ["build_world", "world_xml"],
            "export": ["ExportResult", "export_tum"],
            "node": ["SimNode", "run_sim_node"],
        },
    )
