"""Visual RGB-D SLAM: feature odometry, appearance-based loop closure with a long-term memory, a GTSAM pose
graph, the offline pipeline that composes them, and the SLAM node.

Names are loaded on first use: ``import fleetslam.slam`` imports no submodule, and OpenCV, GTSAM and numba (the
``slam`` extra) are imported only when a name that needs them is used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.slam.backend import Constraint, PoseGraph, make_pose_graph
    from fleetslam.slam.config import BackendConfig, FeatureConfig, OdometryConfig, SlamConfig
    from fleetslam.slam.database import MapDatabase
    from fleetslam.slam.features import FeatureExtractor, Features
    from fleetslam.slam.frontend import (
        FRONT_ENDS,
        KeyframeFeatures,
        KeyframeObservation,
        OdometryFactory,
        OdometryFrontEnd,
        OdometryResult,
        make_odometry,
    )
    from fleetslam.slam.loop_closure import LoopClosureDetector, LoopHypothesis, make_loop_closure_detector
    from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
    from fleetslam.slam.memory import Memory
    from fleetslam.slam.node import SlamNode, SlamNodeConfig
    from fleetslam.slam.odometry import VisualOdometry
    from fleetslam.slam.peer_recognition import PeerMatch, PeerPlaceRecognizer, make_peer_recognizer
    from fleetslam.slam.pipeline import SlamPipeline, SlamResult, StepResult, run_offline
    from fleetslam.slam.signature import Link, LinkType, Signature
    from fleetslam.slam.vocabulary import VisualVocabulary

__all__ = [
    "FRONT_ENDS",
    "BackendConfig",
    "Constraint",
    "FeatureConfig",
    "FeatureExtractor",
    "Features",
    "KeyframeFeatures",
    "KeyframeObservation",
    "Link",
    "LinkType",
    "LoopClosureConfig",
    "LoopClosureDetector",
    "LoopHypothesis",
    "MapDatabase",
    "Memory",
    "MemoryConfig",
    "OdometryConfig",
    "OdometryFactory",
    "OdometryFrontEnd",
    "OdometryResult",
    "PeerMatch",
    "PeerPlaceRecognizer",
    "PoseGraph",
    "Signature",
    "SlamConfig",
    "SlamNode",
    "SlamNodeConfig",
    "SlamPipeline",
    "SlamResult",
    "StepResult",
    "VisualOdometry",
    "VisualVocabulary",
    "make_loop_closure_detector",
    "make_odometry",
    "make_peer_recognizer",
    "make_pose_graph",
    "run_offline",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "config": ["BackendConfig", "FeatureConfig", "OdometryConfig", "SlamConfig"],
            "loop_config": ["LoopClosureConfig", "MemoryConfig"],
            "pipeline": ["SlamPipeline", "SlamResult", "StepResult", "run_offline"],
            "frontend": [
                "FRONT_ENDS",
                "KeyframeFeatures",
                "KeyframeObservation",
                "OdometryFactory",
                "OdometryFrontEnd",
                "OdometryResult",
                "PeerMatch",
                "PeerPlaceRecognizer",
                "make_odometry",
                "make_peer_recognizer",
            ],
            "odometry": ["VisualOdometry"],
            "peer_recognition": ["PeerMatch", "PeerPlaceRecognizer", "make_peer_recognizer"],
            "loop_closure": ["LoopClosureDetector", "LoopHypothesis", "make_loop_closure_detector"],
            "backend": ["Constraint", "PoseGraph", "make_pose_graph"],
            "features": ["FeatureExtractor", "Features"],
            "memory": ["Memory"],
            "database": ["MapDatabase"],
            "signature": ["Link", "LinkType", "Signature"],
            "vocabulary": ["VisualVocabulary"],
            "node": ["SlamNode", "SlamNodeConfig"],
        },
    )
