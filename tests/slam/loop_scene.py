"""Synthetic data for the loop-closure tests: ORB-like binary descriptors and a world of distinct places."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import invert, pose_from_xyz_rpy, transform_points
from fleetslam.slam.frontend import KeyframeFeatures, KeyframeObservation

CAMERA_MATRIX = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 640, 480


def random_descriptors(rng: np.random.Generator, n: int, size: int = 32) -> NDArray[np.uint8]:
    """Random ORB-like 256-bit descriptors."""
    return rng.integers(0, 256, size=(n, size), dtype=np.uint8)


def flip_bits(rng: np.random.Generator, descriptors: NDArray[np.uint8], bits: int) -> NDArray[np.uint8]:
    """Copy of the descriptors with ``bits`` distinct random bits flipped in each."""
    unpacked = np.unpackbits(descriptors, axis=1)
    for row in unpacked:
        row[rng.choice(row.size, size=bits, replace=False)] ^= 1
    return np.packbits(unpacked, axis=1)


@dataclass
class Observation:
    """What a camera at ``pose`` sees of a place."""

    pose: NDArray[np.float64]
    keypoints: NDArray[np.float64]
    points3d: NDArray[np.float64]
    descriptors: NDArray[np.uint8]

    def keyframe(
        self, stamp: float, *, responses: NDArray[np.float64] | None = None, **options: Any
    ) -> KeyframeObservation:
        """What the pipeline hands loop closure for this keyframe (``options``: the other fields)."""
        features = KeyframeFeatures(self.keypoints, self.points3d, self.descriptors, responses)
        return KeyframeObservation(stamp, self.pose, features, **options)


@dataclass
class Place:
    """Landmarks (world points with descriptors) seen from a reference pose."""

    pose: NDArray[np.float64]
    points_world: NDArray[np.float64]
    descriptors: NDArray[np.uint8]


def make_place(rng: np.random.Generator, pose: NDArray[np.float64], n_points: int = 150) -> Place:
    """Points in front of the camera at ``pose`` (optical frame: z forward), with their own descriptors."""
    local = np.column_stack(
        [rng.uniform(-2.0, 2.0, n_points), rng.uniform(-1.5, 1.5, n_points), rng.uniform(2.0, 6.0, n_points)]
    )
    return Place(pose, transform_points(pose, local), random_descriptors(rng, n_points))


def observe(
    rng: np.random.Generator, place: Place, pose: NDArray[np.float64], noise_bits: int = 6, pixel_noise: float = 0.3
) -> Observation:
    """Project the place's points into a camera at ``pose``; keep those in the image, noisy descriptors."""
    local = transform_points(invert(pose), place.points_world)
    in_front = local[:, 2] > 0.1
    uv = (CAMERA_MATRIX @ local.T).T
    uv = uv[:, :2] / uv[:, 2:3]
    visible = in_front & (uv[:, 0] >= 0) & (uv[:, 0] < WIDTH) & (uv[:, 1] >= 0) & (uv[:, 1] < HEIGHT)
    keypoints = uv[visible] + rng.normal(0.0, pixel_noise, size=(int(visible.sum()), 2))
    descriptors = flip_bits(rng, place.descriptors[visible], noise_bits)
    return Observation(pose, keypoints, local[visible], descriptors)


def place_pose(k: int) -> NDArray[np.float64]:
    """Reference pose of place k: 10 m apart along x, looking along +z, slight yaw variation."""
    return pose_from_xyz_rpy(10.0 * k, 0.0, 0.0, 0.0, 0.05 * (k % 3), 0.0)


def revisit_pose(place: Place) -> NDArray[np.float64]:
    """A pose near a place's reference pose (20 cm away, 4 degrees rotated)."""
    return place.pose @ pose_from_xyz_rpy(0.2, -0.05, 0.1, 0.0, np.radians(4.0), np.radians(1.0))
