"""The Kinect v1 depth model and pinhole intrinsics (pure, no rendering)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fleetslam.sim.camera import CameraIntrinsics, KinectModel, intrinsics_from_config
from fleetslam.sim.config import CameraConfig

K = CameraIntrinsics.from_focal(525.0, 640, 480)


def test_intrinsics_kinect_field_of_view_and_scaling() -> None:
    assert K.K[0, 0] == 525.0 and K.K[0, 2] == pytest.approx(319.5)
    assert 55.0 < K.fovx_deg < 65.0 and 42.0 < K.fovy_deg < 50.0
    small = intrinsics_from_config(CameraConfig(), 320, 240)
    assert small.fx == pytest.approx(262.5) and small.cx == pytest.approx(159.5)
    assert K.scaled(320, 240) == small


def test_backproject_inverts_projection() -> None:
    depth = np.full((480, 640), 2.0, dtype=np.float32)
    depth[0, 0] = 0.0
    points = K.backproject(depth)
    assert points.shape == (480 * 640 - 1, 3)
    u = points[:, 0] / points[:, 2] * K.fx + K.cx  # float64 round trip: ~1e-13 px
    v = points[:, 1] / points[:, 2] * K.fy + K.cy
    assert u.min() == pytest.approx(0.0, abs=1e-9) and u.max() == pytest.approx(639.0)
    assert v.min() == pytest.approx(0.0, abs=1e-9) and v.max() == pytest.approx(479.0)


@pytest.mark.parametrize("z", [1.0, 2.0, 3.0, 4.0])
def test_axial_noise_follows_kinect_sigma(z: float) -> None:
    """σ = k·z² holds averaged over where the true disparity falls between two quantisation levels, so the wall
    sweeps its disparity over one step across the image. (A flat wall at 1, 2, 3 or 4 m sits exactly on a level,
    where rounding the Gaussian part leaves 6 % less noise.)"""
    model = KinectModel(K)
    fb = model.disparity_focal * model.baseline
    offset = ((np.arange(640) + 0.5) / 640 - 0.5) * model.disparity_step
    true = np.broadcast_to(fb / (fb / z + offset), (480, 640)).astype(np.float32)
    measured = model.apply(true, np.random.default_rng(1))
    valid = measured > 0
    assert valid.mean() > 0.99
    truth = true[valid].astype(np.float64)
    error = (measured[valid] - truth) / (1.43e-3 * truth**2)  # in units of each pixel's σ
    # 3e5 samples: the s.e. of σ is 1/√(2n) = 0.13 % (≤ 0.27 % off over five seeds); 1 % ≈ 8 s.e.
    assert float(np.std(error)) == pytest.approx(1.0, abs=0.01)
    # 1/d's curvature biases the mean by k·z ≤ 0.6 % of σ; its s.e. is 1/√n = 0.18 % (≤ 0.9 % over five seeds)
    assert abs(float(np.mean(error))) < 0.02


def test_depth_is_quantised_through_disparity() -> None:
    model = KinectModel(K)
    measured = model.apply(np.full((100, 100), 3.0, dtype=np.float32), np.random.default_rng(2))
    disparity = 580.0 * 0.075 / measured[measured > 0].astype(np.float64)
    steps = disparity / 0.125
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)  # float32 depth: ~116 levels × 6e-8 ≈ 1e-5 off
    levels = np.unique(np.round(steps))
    assert 3 <= len(levels) < 30
    gap = model.quantisation_step(3.0)
    assert float(gap) == pytest.approx(9.0 * 0.125 / 43.5)


def test_range_limits_make_pixels_invalid() -> None:
    model = KinectModel(K)
    depth = np.full((60, 80), 2.0, dtype=np.float32)
    depth[:, :20] = 0.3
    depth[:, 60:] = 6.0
    depth[0, 40] = np.nan
    measured = model.apply(depth, np.random.default_rng(3))
    assert np.all(measured[:, :19] == 0) and np.all(measured[:, 61:] == 0)
    assert measured[0, 40] == 0
    assert np.all(measured[5:-5, 25:55] > 0)


def test_depth_edges_and_grazing_angles_are_dropped() -> None:
    model = KinectModel(K)
    depth = np.full((480, 640), 1.5, dtype=np.float32)
    depth[:, 320:] = 3.0
    invalid = model.invalid_mask(depth)
    assert invalid[:, 319].all() and invalid[:, 320].all()
    assert not invalid[10:-10, 100:300].any() and not invalid[10:-10, 340:600].any()
    # a plane through the image with normal n: n·P = d, so z = d / (n · (x/f, y/f, 1))
    b = math.radians(86.0)
    normal = np.array([math.sin(b), 0.0, math.cos(b)])
    rays = K.backproject_image(np.ones((480, 640)))
    denom = rays @ normal
    plane = np.where(denom > 1e-3, 0.25 / np.maximum(denom, 1e-3), 0.0)
    incidence = np.degrees(np.arccos(np.clip(denom / np.linalg.norm(rays, axis=-1), -1, 1)))
    in_range = (plane > 0.6) & (plane < 4.0)
    mask = model.invalid_mask(plane.astype(np.float32))
    inner = np.zeros_like(in_range)
    inner[5:-5, 5:-5] = True
    steep = in_range & inner & (incidence > 83.0)
    gentle = in_range & inner & (incidence < 76.0)
    assert steep.sum() > 1000 and gentle.sum() > 1000
    # 3° and 4° either side of the 80° limit absorb the float32 gradients' error: 1.0 and 0.0 measured
    assert mask[steep].mean() > 0.98
    assert mask[gentle].mean() < 0.02
