"""Point-to-plane alignment of a depth image to a keyframe's surface: it recovers a motion from geometry alone,
and it holds a pose that a handful of feature matches leave loose."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle
from fleetslam.slam.pose_refinement import refine_pose
from fleetslam.slam.surface_alignment import KeyframeSurface, SurfaceTerm, depth_samples, sample_stride

from .finite_differences import jacobian_agreement

INTRINSICS = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
#: A room corner in the keyframe's camera frame (x right, y down, z forward): (normal, offset) with n·p = offset.
PLANES = [
    (np.array([0.0, 0.0, 1.0]), 3.0),  # the wall ahead
    (np.array([0.0, 1.0, 0.0]), 0.8),  # the floor below
    (np.array([1.0, 0.0, 0.0]), -1.5),  # a wall on the left
]
DEPTH_NOISE = 1.5e-3


def render_depth(T_world_camera: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """The corner's depth image from a camera at ``T_world_camera`` (Kinect-like noise when ``rng`` is given)."""
    k = INTRINSICS
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1)  # z = 1 in the camera
    origin = T_world_camera[:3, 3]
    directions = rays @ T_world_camera[:3, :3].T
    depth = np.full(u.shape, np.inf)
    for normal, offset in PLANES:
        along = directions @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - origin @ normal) / along
        depth = np.where((t > 0) & (t < depth), t, depth)  # t is the camera-frame z, rays having z = 1
    depth[~np.isfinite(depth)] = 0.0
    if rng is not None:
        depth = depth + rng.normal(0.0, 1.0, depth.shape) * (DEPTH_NOISE * depth**2 + 1e-3) * (depth > 0)
    return depth.astype(np.float32)


def surface_term(keyframe_pose: np.ndarray, frame_pose: np.ndarray, rng: np.random.Generator) -> SurfaceTerm:
    stride = sample_stride(INTRINSICS, 3000)
    surface = KeyframeSurface.from_depth(render_depth(keyframe_pose, rng), INTRINSICS, stride, 0.1, 6.0)
    points = depth_samples(render_depth(frame_pose, rng), INTRINSICS, stride, 0.1, 6.0)
    return SurfaceTerm(surface, keyframe_pose, points, DEPTH_NOISE)


def test_normals_of_a_plane_face_the_camera() -> None:
    surface = KeyframeSurface.from_depth(render_depth(np.eye(4)), INTRINSICS, 4, 0.1, 6.0)
    centre = surface.normals[surface.valid.shape[0] // 3, surface.valid.shape[1] // 2]
    # The wall ahead: n·p = 3 faces the camera as (0, 0, -1).
    np.testing.assert_allclose(centre, [0.0, 0.0, -1.0], atol=1e-9)
    # No normal across the edges where two planes meet at different depths, none at the border.
    assert not surface.valid[0].any() and not surface.valid[:, -1].any()
    assert surface.valid.mean() > 0.8


@pytest.mark.parametrize(
    "motion",
    [pose_from_xyz_rpy(0.02, -0.01, 0.03, 0.01, -0.015, 0.02), pose_from_xyz_rpy(-0.03, 0.01, -0.01, 0.0, 0.02, -0.01)],
)
def test_geometry_alone_recovers_a_motion(motion: np.ndarray) -> None:
    """From the keyframe's pose (no motion known), a frame-to-frame motion of a few centimetres: the term's basin
    is its association distance (5 cm)."""
    rng = np.random.default_rng(0)
    keyframe, frame = np.eye(4), motion
    term = surface_term(keyframe, frame, rng)
    none = np.zeros((0, 3))
    estimate = invert(refine_pose(invert(keyframe), none, np.zeros((0, 2)), INTRINSICS.K, iterations=10, dense=[term]))
    error = invert(frame) @ estimate
    # Three orthogonal planes fix all six degrees of freedom; with a Kinect's noise on every pixel (1.4 cm at 3 m)
    # 2.6 and 3.2 mm, 0.07° measured.
    assert np.linalg.norm(error[:3, 3]) < 5e-3
    assert np.degrees(rotation_angle(error)) < 0.2


def test_residuals_vanish_at_the_true_pose_and_grow_away_from_it() -> None:
    rng = np.random.default_rng(1)
    frame = pose_from_xyz_rpy(0.02, 0.0, 0.03, 0.0, 0.01, 0.0)
    term = surface_term(np.eye(4), frame, rng)
    at_truth, jacobian = term.linearize(invert(frame))
    assert jacobian.shape == (len(at_truth), 6)
    assert len(at_truth) > 1000
    # Whitened by the depth noise: about one standard deviation each where the pose is right (less: the
    # keyframe's surface is averaged over a stride).
    rms_at_truth = np.sqrt(np.mean(at_truth**2))
    assert rms_at_truth < 1.5
    off, _ = term.linearize(invert(frame @ pose_from_xyz_rpy(0.02, 0.02, 0.02, 0.0, 0.0, 0.0)))
    assert np.sqrt(np.mean(off**2)) > 1.5 * rms_at_truth  # 1.9 times measured


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(2)
    frame = pose_from_xyz_rpy(0.02, 0.01, 0.03, 0.0, 0.01, 0.02)
    term = surface_term(np.eye(4), frame, rng)
    # A sample whose projection crosses into the next grid cell changes its pair (a few in thousands).
    for axis, agree in enumerate(jacobian_agreement(term, invert(frame), rtol=1e-3, atol=1e-2)):
        assert agree > 0.99, f"axis {axis}: {agree:.4f} of the rows agree"
