from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from fleetslam.robot.kinematics import body_twist, wheel_speeds
from fleetslam.robot.odometry import Odometry, integrate_arc

R, L = 0.075, 0.40


@pytest.mark.parametrize(("v", "omega"), [(0.5, 0.0), (0.0, 1.0), (0.3, -0.7), (-0.2, 0.4)])
def test_wheel_speeds_match_the_equations_and_invert(v: float, omega: float) -> None:
    left, right = wheel_speeds(v, omega, wheel_radius=R, wheel_separation=L)
    assert right == pytest.approx((2 * v + omega * L) / (2 * R))
    assert left == pytest.approx((2 * v - omega * L) / (2 * R))
    assert body_twist(left, right, wheel_radius=R, wheel_separation=L) == pytest.approx((v, omega))


def test_turning_in_place_spins_wheels_opposite() -> None:
    left, right = wheel_speeds(0.0, 1.0, wheel_radius=R, wheel_separation=L)
    assert left == pytest.approx(-right)
    assert right > 0


def _drive(odom: Odometry, v: float, omega: float, duration: float, steps: int) -> None:
    left_rate, right_rate = wheel_speeds(v, omega, wheel_radius=R, wheel_separation=L)
    for k in range(steps + 1):
        t = duration * k / steps
        odom.update(left_rate * t, right_rate * t, t)


def test_odometry_is_exact_on_a_circle_with_coarse_steps() -> None:
    v, omega, duration = 0.4, 0.5, 10.0
    odom = Odometry(wheel_radius=R, wheel_separation=L)
    odom.reset(1.0, -2.0, 0.3)
    _drive(odom, v, omega, duration, steps=7)  # steps of 0.71 rad: only an exact arc step stays on the circle
    radius = v / omega
    theta = 0.3 + omega * duration
    expected_x = 1.0 + radius * (math.sin(theta) - math.sin(0.3))
    expected_y = -2.0 - radius * (math.cos(theta) - math.cos(0.3))
    state = odom.state()
    # Exact arc steps leave round-off only (2e-15 measured); a midpoint step of 0.71 rad would be ~cm off.
    assert state.x == pytest.approx(expected_x, abs=1e-9)
    assert state.y == pytest.approx(expected_y, abs=1e-9)
    assert math.cos(state.theta - theta) == pytest.approx(1.0)
    assert state.v == pytest.approx(v)
    assert state.omega == pytest.approx(omega)


def test_odometry_is_exact_on_a_straight_line() -> None:
    odom = Odometry(wheel_radius=R, wheel_separation=L)
    odom.reset(0.0, 0.0, math.radians(30))
    _drive(odom, 0.5, 0.0, 4.0, steps=3)
    state = odom.state()
    # Straight steps: three products and sums of float64 (~2e-16 measured)
    assert state.x == pytest.approx(2.0 * math.cos(math.radians(30)), abs=1e-12)
    assert state.y == pytest.approx(2.0 * math.sin(math.radians(30)), abs=1e-12)
    assert state.theta == pytest.approx(math.radians(30))


def test_tiny_rotation_uses_the_midpoint_step_continuously() -> None:
    exact = integrate_arc(0.0, 0.0, 0.0, 1.0, 2e-6)
    mid = integrate_arc(0.0, 0.0, 0.0, 1.0, 0.9e-6)
    # 1 − cos(2e-6) cancels: float64 leaves a relative error ~eps/dθ² ≈ 6e-5 (2.2e-5 measured)
    assert exact[1] == pytest.approx(1e-6, rel=1e-3)
    assert mid[1] == pytest.approx(0.45e-6, rel=1e-3)


def test_fixed_covariance_diagonal_is_reported() -> None:
    diag = (0.01, 0.02, 1e3, 1e3, 1e3, 0.05)
    odom = Odometry(wheel_radius=R, wheel_separation=L, pose_covariance_diagonal=diag)
    state = odom.update(0.0, 0.0, 0.0)
    assert state.pose_covariance.shape == (6, 6)
    assert np.allclose(np.diag(state.pose_covariance), diag)


def test_propagated_covariance_grows_with_distance_and_matches_monte_carlo() -> None:
    k = 0.02
    rng = np.random.default_rng(4)
    steps, d_left, d_right = 50, 0.4, 0.5
    odom = Odometry(wheel_radius=R, wheel_separation=L, propagate=True, encoder_noise=k)
    odom.update(0.0, 0.0, 0.0)
    variances = []
    for i in range(1, steps + 1):
        state = odom.update(d_left * i, d_right * i, 0.1 * i)
        variances.append(state.pose_covariance[0, 0] + state.pose_covariance[1, 1])
    assert all(b >= a for a, b in itertools.pairwise(variances))
    # Monte Carlo of the same noise model as an oracle
    finals = []
    for _ in range(400):
        mc = Odometry(wheel_radius=R, wheel_separation=L)
        mc.update(0.0, 0.0, 0.0)
        pl = pr = 0.0
        for i in range(1, steps + 1):
            pl += d_left + rng.normal(0.0, k * math.sqrt(d_left))
            pr += d_right + rng.normal(0.0, k * math.sqrt(d_right))
            mc.update(pl, pr, 0.1 * i)
        finals.append((mc.x, mc.y, mc.theta))
    sample = np.cov(np.array(finals).T)
    planar = state.pose_covariance[np.ix_([0, 1, 5], [0, 1, 5])]
    # Sample variances of 400 runs: relative s.e. √(2/399) ≈ 0.07, so 0.3 ≈ 4σ (0.12 with this seed).
    assert np.allclose(np.diag(planar), np.diag(sample), rtol=0.3)
