"""Adding an odometry front-end: wheel odometry alone, registered as ``odometry.kind = "wheels"``.

The front-end follows each frame's wheel-odometry pose (``RGBDFrame.prior``) and makes a keyframe every
``odometry.keyframe_translation`` metres or ``odometry.keyframe_rotation_deg`` degrees. It gives no features, so
the pipeline runs with loop closure off and writes no map.db. The frames come from a synthetic drive (a circle,
with a slipping left wheel) made here, an :class:`~fleetslam.datasets.base.RGBDSource` like a TUM folder's.

    python examples/wheel_odometry_frontend.py --frames 60 --out /tmp/wheels

prints one JSON line: frames, keyframes, whether loop closure ran, and the ATE against the true drive.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fleetslam.config import load_config
from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.eval import ape
from fleetslam.geometry import invert, make_pose, pose_from_planar, rotation_angle
from fleetslam.slam.config import FeatureConfig, OdometryConfig, SlamConfig
from fleetslam.slam.frontend import FRONT_ENDS, OdometryFrontEnd, OdometryResult
from fleetslam.slam.pipeline import run_offline
from fleetslam.trajectory import Trajectory

#: The camera on the robot (T_base_camera): 0.3 m up, looking forward (optical x right, y down, z along the base's x).
BASE_CAMERA = make_pose([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], [0.0, 0.0, 0.3])


class WheelOdometry:
    """An :class:`~fleetslam.slam.frontend.OdometryFrontEnd` that trusts the wheels: the frame's pose is its prior
    relative to the first frame's (the map frame is the first camera frame, as with the visual odometry)."""

    provides_features = False

    def __init__(self, config: OdometryConfig, base_camera: NDArray[np.float64] | None = None) -> None:
        self.config = config
        self.base_camera = base_camera
        self._first: NDArray[np.float64] | None = None
        self._pose = np.eye(4)
        self._keyframe: NDArray[np.float64] | None = None

    def track(
        self, rgb: NDArray[np.uint8], depth: NDArray[np.float32], stamp: float, prior: NDArray[np.float64] | None = None
    ) -> OdometryResult:
        lost = prior is None
        if prior is not None:
            if self._first is None:
                self._first = prior
            self._pose = invert(self._first) @ prior
        moved = self._keyframe is None
        if self._keyframe is not None:
            motion = invert(self._keyframe) @ self._pose
            moved = bool(
                np.linalg.norm(motion[:3, 3]) >= self.config.keyframe_translation
                or rotation_angle(motion) >= np.radians(self.config.keyframe_rotation_deg)
            )
        if moved:
            self._keyframe = self._pose.copy()
        # Without a prior the pose stays where it was: "lost", and the graph links it loosely.
        return OdometryResult(pose=self._pose.copy(), inliers=0, matches=0, is_keyframe=moved, lost=lost)

    def local_mapping(self) -> NDArray[np.float64] | None:
        return None  # nothing deferred

    def constrain(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        return pose

    def relocalize(self, result: OdometryResult, pose: NDArray[np.float64]) -> OdometryResult:
        # Never called without features (no loop closure, no relocalisation); kept for the protocol.
        result.pose = pose
        return result


def make_wheel_odometry(
    config: OdometryConfig, features: FeatureConfig, intrinsics: Intrinsics, base_camera: NDArray[np.float64] | None
) -> OdometryFrontEnd:
    """The registry's factory: the same arguments as the built-in ``visual`` front-end's."""
    return WheelOdometry(config, base_camera)


class SyntheticDrive:
    """A robot driving a circle of 1 m radius at 0.3 m/s, filmed at 10 Hz: flat grey frames (the wheel
    front-end never looks at them), the true camera pose, and the wheel odometry with the left wheel slipping 2 %."""

    name = "synthetic_drive"

    def __init__(self, frames: int) -> None:
        self.intrinsics = Intrinsics(160.0, 160.0, 79.5, 59.5, 160, 120)
        self.base_camera = BASE_CAMERA
        self.count = frames
        dt, speed, radius = 0.1, 0.3, 1.0
        self.stamps = np.arange(frames) * dt
        self.truth = [self._base(speed * t / radius, radius) @ BASE_CAMERA for t in self.stamps]
        self.wheels = [self._base(0.98 * speed * t / radius, radius * 1.01) @ BASE_CAMERA for t in self.stamps]

    @staticmethod
    def _base(angle: float, radius: float) -> NDArray[np.float64]:
        return pose_from_planar(radius * np.sin(angle), radius * (1.0 - np.cos(angle)), angle)

    def __len__(self) -> int:
        return self.count

    def __iter__(self) -> Iterator[RGBDFrame]:
        return self.frames()

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        size = (self.intrinsics.height, self.intrinsics.width)
        for i in range(0, self.count, every):
            rgb = np.full((*size, 3), 128, np.uint8)
            depth = np.full(size, 2.0, np.float32)
            yield RGBDFrame(i, float(self.stamps[i]), rgb, depth, prior=self.wheels[i], groundtruth=self.truth[i])

    def groundtruth(self) -> Trajectory:
        return Trajectory.from_lists(list(self.stamps), self.truth)


def main(argv: list[str] | None = None) -> dict[str, object]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--out", type=Path, default=Path("results/wheel_odometry_frontend"))
    args = parser.parse_args(argv)
    source = SyntheticDrive(args.frames)
    config = load_config(SlamConfig, overrides=["odometry.kind=wheels"])
    front_ends = {**FRONT_ENDS, "wheels": make_wheel_odometry}
    result = run_offline(source, config, args.out, show_progress=False, front_ends=front_ends)
    summary: dict[str, object] = {
        "frames": len(result.trajectory),
        "keyframes": len(result.keyframes),
        "loop_closure": (args.out / "map.db").exists(),
        "ate_cm": round(100.0 * ape(source.groundtruth(), result.trajectory).rmse, 3),
        "out": str(args.out),
    }
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
