"""The seam between an odometry front-end and the rest of the SLAM: what a front-end is, what it gives per frame
and per keyframe, and the typed registry that configuration (``odometry.kind``) selects from.

A front-end tracks frames (:meth:`OdometryFrontEnd.track` → :class:`OdometryResult`); the pipeline adds its
keyframes to the pose graph and hands loop closure a :class:`KeyframeObservation`. A front-end that gives no
features (``provides_features`` false: wheel odometry alone, a depth-only tracker) runs with loop closure and
relocalisation off. A new front-end is a class with these members and a factory in the registry passed to
:class:`~fleetslam.slam.pipeline.SlamPipeline` (``front_ends``), e.g.
``SlamPipeline(config, source, front_ends={**FRONT_ENDS, "wheels": make_wheel_odometry})`` with
``odometry.kind = "wheels"``; ``docs/extending.md`` walks through one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.errors import ConfigError
from fleetslam.slam.config import FeatureConfig, OdometryConfig


@dataclass
class OdometryResult:
    """Outcome of :meth:`OdometryFrontEnd.track` for one frame."""

    pose: NDArray[np.float64]
    """``T_world_camera`` in the odometry frame."""
    inliers: int
    """Landmarks the pose was estimated from (0 when lost or coasting)."""
    matches: int
    """Descriptor matches against the local map."""
    is_keyframe: bool
    lost: bool
    """Visual tracking failed and no wheel odometry carried the pose (it follows constant velocity)."""
    timings: dict[str, float] = field(default_factory=dict)
    """Milliseconds per step (features, match, pose, keyframe, total)."""
    keypoints: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    """Keypoints with valid depth (for the loop-closure side on keyframes)."""
    points3d: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """Their 3D points in the camera frame."""
    descriptors: NDArray[Any] = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    responses: NDArray[np.float32] = field(default_factory=lambda: np.zeros(0, np.float32))
    """Their detector responses (strength)."""
    coasting: bool = False
    """Visual tracking failed and the pose follows the wheel odometry; the map is kept."""
    map_restarted: bool = False
    """The local map was started afresh at this frame (first frame, or after losing it)."""

    def features(self) -> KeyframeFeatures:
        """The keypoints, 3D points, descriptors and responses, as loop closure takes them."""
        return KeyframeFeatures(self.keypoints, self.points3d, self.descriptors, self.responses)


@dataclass(frozen=True)
class KeyframeFeatures:
    """What a keyframe saw, for loop closure and relocalisation: keypoints with their 3D points and descriptors."""

    keypoints: NDArray[np.floating]
    """``(N, 2)`` pixel coordinates."""
    points3d: NDArray[np.floating]
    """``(N, 3)`` the keypoints' points in the camera frame (metres)."""
    descriptors: NDArray[Any]
    """``(N, D)`` descriptors (uint8 for binary ones)."""
    responses: NDArray[np.floating] | None = None
    """``(N,)`` detector responses: which keypoints become words when the memory limits them (None: the first)."""


@dataclass(frozen=True)
class KeyframeObservation:
    """One keyframe as loop closure receives it (:meth:`~fleetslam.slam.loop_closure.LoopClosureDetector.process`,
    :meth:`~fleetslam.slam.memory.Memory.add`)."""

    stamp: float
    """Capture time (seconds)."""
    pose: NDArray[np.float64]
    """``T_world_camera`` in the odometry frame."""
    features: KeyframeFeatures | None = None
    """What it saw; None from a front-end without features (loop closure cannot use the keyframe)."""
    odometry_transform: NDArray[np.float64] | None = None
    """``T_previous_new`` from the odometry (None: computed from the poses)."""
    odometry_information: NDArray[np.float64] | None = None
    """6×6 information of that link (None: identity)."""
    rgb_compressed: bytes | None = None
    """The colour image (JPEG), kept with the location when the memory keeps images."""
    depth_compressed: bytes | None = None
    """The depth image (PNG), likewise."""


class OdometryFrontEnd(Protocol):
    """What the pipeline needs of an odometry: ``track`` once per frame, in order, then ``local_mapping``."""

    base_camera: NDArray[np.float64] | None
    """The camera's mounting on a ground robot (``T_base_camera``), set by the pipeline when it becomes known."""

    @property
    def provides_features(self) -> bool:
        """Keyframes carry features (``OdometryResult.keypoints`` ...): without them loop closure is off."""
        ...

    def track(
        self, rgb: NDArray[np.uint8], depth: NDArray[np.float32], stamp: float, prior: NDArray[np.float64] | None = None
    ) -> OdometryResult:
        """The frame's ``T_world_camera`` (``prior``: its pose from wheel odometry in any fixed frame, if known)."""
        ...

    def local_mapping(self) -> NDArray[np.float64] | None:
        """Work deferred after the frame's pose is out; the last frame's refined pose, or None if nothing ran."""
        ...

    def constrain(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """A transform projected onto the robot's motion model (a ground robot's plane), or unchanged."""
        ...

    def relocalize(self, result: OdometryResult, pose: NDArray[np.float64]) -> OdometryResult:
        """Put a lost frame back on the map at ``pose`` (found by loop closure) and continue from there."""
        ...


OdometryFactory = Callable[[OdometryConfig, FeatureConfig, Intrinsics, NDArray[np.float64] | None], OdometryFrontEnd]
"""Builds a front-end from the odometry and feature sections, the camera and its mounting (T_base_camera)."""


def _visual_odometry(
    config: OdometryConfig, features: FeatureConfig, intrinsics: Intrinsics, base_camera: NDArray[np.float64] | None
) -> OdometryFrontEnd:
    from fleetslam.slam.odometry import VisualOdometry

    return VisualOdometry(config, intrinsics, features, base_camera)


FRONT_ENDS: Mapping[str, OdometryFactory] = MappingProxyType({"visual": _visual_odometry})
"""The front-ends ``odometry.kind`` names: ``visual`` (:class:`~fleetslam.slam.odometry.VisualOdometry`)."""


def make_odometry(
    config: OdometryConfig,
    features: FeatureConfig,
    intrinsics: Intrinsics,
    base_camera: NDArray[np.float64] | None = None,
    *,
    front_ends: Mapping[str, OdometryFactory] = FRONT_ENDS,
) -> OdometryFrontEnd:
    """Build the front-end that ``config.kind`` names in ``front_ends``.

    Raises:
        ConfigError: no front-end of that kind.
    """
    factory = front_ends.get(config.kind)
    if factory is None:
        raise ConfigError(f"odometry.kind = {config.kind!r} is unknown; known kinds: {sorted(front_ends)}")
    return factory(config, features, intrinsics, base_camera)
