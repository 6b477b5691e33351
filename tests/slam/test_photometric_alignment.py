"""Photometric alignment of a frame to a keyframe's image: it recovers a motion from the image's edges alone, its
Jacobian is the derivative of its residuals, and the pixels it compares are spread over the image."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle
from fleetslam.slam.photometric_alignment import (
    FrameIntensity,
    KeyframeIntensity,
    PhotometricTerm,
    level_intrinsics,
    pyramid_level,
)
from fleetslam.slam.pose_refinement import refine_pose
from fleetslam.slam.surface_alignment import KeyframeSurface, SurfaceTerm, depth_samples, sample_stride

from .finite_differences import jacobian_agreement

INTRINSICS = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
#: A room corner in the world (x right, y down, z forward from the first camera): (normal, offset), n·p = offset.
PLANES = [
    (np.array([0.0, 0.0, 1.0]), 3.0),  # the wall ahead
    (np.array([0.0, 1.0, 0.0]), 0.8),  # the floor below
    (np.array([1.0, 0.0, 0.0]), -1.5),  # a wall on the left
]


def render(
    T_world_camera: np.ndarray,
    rng: np.random.Generator,
    planes: list[tuple[np.ndarray, float]] = PLANES,
    intrinsics: Intrinsics = INTRINSICS,
) -> tuple[np.ndarray, np.ndarray]:
    """Grey image (uint8, with sensor noise) and depth (float32 m) of the planes (default: the corner), whose
    surfaces carry smooth stripes (edges, no corners for a feature detector to find)."""
    k = intrinsics
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1)
    origin = T_world_camera[:3, 3]
    directions = rays @ T_world_camera[:3, :3].T
    depth = np.full(u.shape, np.inf)
    for normal, offset in planes:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - origin @ normal) / (directions @ normal)
        depth = np.where((t > 0) & (t < depth), t, depth)
    depth[~np.isfinite(depth)] = 0.0
    world = origin + directions * depth[..., None]
    shade = 128 + 60 * np.sin(7.0 * world[..., 0] + 3.0 * world[..., 2]) + 40 * np.sin(9.0 * world[..., 1])
    gray = np.clip(shade + rng.normal(0.0, 1.0, shade.shape), 0, 255).astype(np.uint8)
    return gray, depth.astype(np.float32)


def photometric_term(keyframe_pose: np.ndarray, frame_pose: np.ndarray, seed: int) -> PhotometricTerm:
    rng = np.random.default_rng(seed)
    key_gray, key_depth = render(keyframe_pose, rng)
    frame_gray, _ = render(frame_pose, rng)
    key_intensity = FrameIntensity.from_gray(key_gray, INTRINSICS, blur_px=1.0)
    selected = KeyframeIntensity.select(key_intensity, key_depth, 7, 4.0, 0.1, 6.0)
    return PhotometricTerm(selected, keyframe_pose, FrameIntensity.from_gray(frame_gray, INTRINSICS, 1.0), 8.0)


def test_selected_pixels_are_spread_and_carry_their_depth() -> None:
    rng = np.random.default_rng(0)
    gray, depth = render(np.eye(4), rng)
    intensity = FrameIntensity.from_gray(gray, INTRINSICS, blur_px=1.0)
    selected = KeyframeIntensity.select(intensity, depth, 8, 4.0, 0.1, 6.0)
    # At most one pixel per 8×8 block (40×30 blocks), most blocks striped enough to give one.
    assert 0.6 * 1200 < len(selected.points) <= 1200
    u = selected.points[:, 0] * INTRINSICS.fx / selected.points[:, 2] + INTRINSICS.cx
    v = selected.points[:, 1] * INTRINSICS.fy / selected.points[:, 2] + INTRINSICS.cy
    assert np.ptp(u) > 0.9 * INTRINSICS.width and np.ptp(v) > 0.9 * INTRINSICS.height
    # Each point lies on the plane it was seen on (within float32 depth rounding).
    on_plane = [np.abs(selected.points @ n - offset) < 1e-5 for n, offset in PLANES]
    assert np.logical_or.reduce(on_plane).all()


@pytest.mark.parametrize(
    "motion",
    [pose_from_xyz_rpy(0.02, -0.01, 0.03, 0.01, -0.015, 0.02), pose_from_xyz_rpy(-0.03, 0.01, -0.01, 0.0, 0.02, -0.01)],
)
def test_intensity_alone_recovers_a_motion(motion: np.ndarray) -> None:
    """From the keyframe's pose (no motion known), a motion of a few centimetres and about a degree: a few
    pixels, inside the smoothed images' basin."""
    term = photometric_term(np.eye(4), motion, seed=1)
    none = np.zeros((0, 3))
    estimate = invert(refine_pose(np.eye(4), none, np.zeros((0, 2)), INTRINSICS.K, iterations=15, dense=[term]))
    error = invert(motion) @ estimate
    # 0.4-0.8 mm and 0.006-0.015° measured: the stripes fix every degree of freedom; bounds with a margin for the
    # noise and the interpolation.
    assert np.linalg.norm(error[:3, 3]) < 3e-3
    assert np.degrees(rotation_angle(error)) < 0.1


def test_residuals_vanish_at_the_true_pose_and_grow_away_from_it() -> None:
    frame = pose_from_xyz_rpy(0.02, 0.0, 0.03, 0.0, 0.01, 0.0)
    term = photometric_term(np.eye(4), frame, seed=2)
    at_truth, jacobian = term.linearize(invert(frame))
    assert jacobian.shape == (len(at_truth), 6) and len(at_truth) > 800
    rms_at_truth = np.sqrt(np.mean(at_truth**2))
    assert rms_at_truth < 0.2  # noise of 1 grey level (less after smoothing) over σ = 8: 0.05 measured
    off, _ = term.linearize(invert(frame @ pose_from_xyz_rpy(0.01, 0.01, 0.0, 0.0, 0.0, 0.0)))
    assert np.sqrt(np.mean(off**2)) > 3 * rms_at_truth  # 12 times measured


def test_jacobian_matches_finite_differences() -> None:
    frame = pose_from_xyz_rpy(0.02, 0.01, 0.03, 0.0, 0.01, 0.02)
    term = photometric_term(np.eye(4), frame, seed=3)
    # Bilinear interpolation has kinks at pixel borders: the image gradient and the interpolated slope differ a
    # little for a pixel near one (95-99 % of the rows agree, measured).
    for axis, agree in enumerate(jacobian_agreement(term, invert(frame), rtol=0.2, atol=0.05)):
        assert agree > 0.9, f"axis {axis}: {agree:.4f} of the rows agree"


def test_edges_hold_the_motion_that_a_plain_wall_leaves_to_the_surface_term_free() -> None:
    """A single wall ahead: its depth fixes the distance and the tilt but not a slide along it or a roll about
    its normal. With the photometric term the stripes fix those too."""
    wall = [PLANES[0]]
    motion = pose_from_xyz_rpy(0.03, -0.02, 0.01, 0.0, 0.0, np.radians(0.8))
    rng = np.random.default_rng(4)
    key_gray, key_depth = render(np.eye(4), rng, wall)
    frame_gray, frame_depth = render(motion, rng, wall)
    stride = sample_stride(INTRINSICS, 3000)
    surface = SurfaceTerm(
        KeyframeSurface.from_depth(key_depth, INTRINSICS, stride, 0.1, 6.0), np.eye(4),
        depth_samples(frame_depth, INTRINSICS, stride, 0.1, 6.0), 1.5e-3,
    )  # fmt: skip
    intensity = FrameIntensity.from_gray(key_gray, INTRINSICS, 1.0)
    photometric = PhotometricTerm(
        KeyframeIntensity.select(intensity, key_depth, 7, 4.0, 0.1, 6.0), np.eye(4),
        FrameIntensity.from_gray(frame_gray, INTRINSICS, 1.0), 8.0,
    )  # fmt: skip
    none, no_pixels = np.zeros((0, 3)), np.zeros((0, 2))

    def error_cm(dense: list) -> float:  # type: ignore[type-arg]
        estimate = invert(refine_pose(np.eye(4), none, no_pixels, INTRINSICS.K, iterations=15, dense=dense))
        return float(np.linalg.norm((invert(motion) @ estimate)[:3, 3]) * 100)

    # Depth alone: the slide stays where it started (3.6 cm off, measured); with the stripes 0.005 cm.
    assert error_cm([surface]) > 3.0
    assert error_cm([surface, photometric]) < 0.3


def test_a_pyramid_level_recovers_the_same_motion_at_a_quarter_of_the_pixels() -> None:
    """A 640×480 image worked on at its 320×240 level: the level's intrinsics put the selected pixels where the
    full image's would be, and the motion comes out as on a 320×240 camera."""
    big = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
    assert pyramid_level(640) == 1 and pyramid_level(320) == 0 and pyramid_level(1280) == 2 and pyramid_level(480) == 0
    level = level_intrinsics(big, 1)
    assert (level.width, level.height, level.fx, level.cx) == (320, 240, 262.5, 159.75)
    motion = pose_from_xyz_rpy(0.02, -0.01, 0.03, 0.01, -0.015, 0.02)
    rng = np.random.default_rng(5)
    key_gray, key_depth = render(np.eye(4), rng, intrinsics=big)
    frame_gray, _ = render(motion, rng, intrinsics=big)
    key = FrameIntensity.from_gray(key_gray, big, 1.0, level=1)
    selected = KeyframeIntensity.select(key, key_depth, 7, 4.0, 0.1, 6.0)
    # Each selected point projects, in the full image, where its level pixel sits (pixel i on pixel 2i).
    u = selected.points[:, 0] * big.fx / selected.points[:, 2] + big.cx
    np.testing.assert_allclose(u / 2.0 - np.round(u / 2.0), 0.0, atol=1e-3)
    term = PhotometricTerm(selected, np.eye(4), FrameIntensity.from_gray(frame_gray, big, 1.0, level=1), 8.0)
    none = np.zeros((0, 3))
    estimate = invert(refine_pose(np.eye(4), none, np.zeros((0, 2)), big.K, iterations=15, dense=[term]))
    error = invert(motion) @ estimate
    assert np.linalg.norm(error[:3, 3]) < 3e-3  # as on a 320×240 camera (the bounds of the test above)
    assert np.degrees(rotation_angle(error)) < 0.1
