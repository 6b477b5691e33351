"""Wheel odometry: integrate encoder increments into a planar pose with covariance.

Each step moves along the exact circular arc swept by the wheel increments; when the heading change is
tiny the arc radius is ill-conditioned, so a second-order Runge–Kutta step (heading at mid-step) is used
instead, as ros2_control's diff_drive_controller does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import normalize_angle
from fleetslam.robot.kinematics import body_increment

#: below this heading change (rad) the arc formula loses precision; use the mid-point step.
_SMALL_ANGLE = 1e-6

Covariance = NDArray[np.float64]


@dataclass(frozen=True)
class OdometryState:
    """Pose (x, y, θ) in the odom frame, body twist (v, ω) and their 6×6 covariances at ``stamp`` (s)."""

    stamp: float
    x: float
    y: float
    theta: float
    v: float
    omega: float
    pose_covariance: Covariance = field(repr=False)
    """Row-major 6×6 over (x, y, z, roll, pitch, yaw), as nav_msgs/Odometry."""
    twist_covariance: Covariance = field(repr=False)
    """Row-major 6×6 over (vx, vy, vz, wx, wy, wz)."""


def integrate_arc(x: float, y: float, theta: float, ds: float, dtheta: float) -> tuple[float, float, float]:
    """Pose after moving ``ds`` along an arc that turns by ``dtheta`` from (x, y, θ)."""
    if abs(dtheta) < _SMALL_ANGLE:
        mid = theta + 0.5 * dtheta
        return x + ds * math.cos(mid), y + ds * math.sin(mid), theta + dtheta
    radius = ds / dtheta
    new_theta = theta + dtheta
    return (
        x + radius * (math.sin(new_theta) - math.sin(theta)),
        y - radius * (math.cos(new_theta) - math.cos(theta)),
        new_theta,
    )


class Odometry:
    """Integrates cumulative wheel angles (rad) into pose and twist.

    Args:
        wheel_radius: r, m.
        wheel_separation: L, m.
        pose_covariance_diagonal: fixed diagonal (x, y, z, roll, pitch, yaw) used unless ``propagate``.
        twist_covariance_diagonal: fixed diagonal (vx, vy, vz, wx, wy, wz).
        propagate: grow the planar pose covariance from encoder noise instead.
        encoder_noise: k in σ²(Δφ) = k²·|Δφ| for each wheel's angle increment, rad/√rad.
    """

    def __init__(
        self,
        *,
        wheel_radius: float,
        wheel_separation: float,
        pose_covariance_diagonal: tuple[float, ...] = (0.001, 0.001, 1e6, 1e6, 1e6, 0.01),
        twist_covariance_diagonal: tuple[float, ...] = (0.001, 0.001, 1e6, 1e6, 1e6, 0.01),
        propagate: bool = False,
        encoder_noise: float = 0.01,
    ) -> None:
        self.wheel_radius = wheel_radius
        self.wheel_separation = wheel_separation
        self._pose_diag = np.asarray(pose_covariance_diagonal, dtype=np.float64)
        self._twist_cov = np.diag(np.asarray(twist_covariance_diagonal, dtype=np.float64))
        self.propagate = propagate
        self.encoder_noise = encoder_noise
        self._prev: tuple[float, float] | None = None
        self._stamp = 0.0
        self.x = 0.0
        self.y = 0.0
        self.theta = 0.0
        self.v = 0.0
        self.omega = 0.0
        # planar (x, y, θ) covariance, used when propagating
        self._planar_cov = np.zeros((3, 3))

    def reset(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> None:
        """Restart from (x, y, θ) with zero covariance; the next encoder reading becomes the reference."""
        self.x, self.y, self.theta = x, y, theta
        self.v = self.omega = 0.0
        self._prev = None
        self._planar_cov = np.zeros((3, 3))

    def update(self, left_position: float, right_position: float, now: float) -> OdometryState:
        """Integrate from cumulative wheel angles (rad) read at ``now`` (s); returns the new state."""
        if self._prev is None:
            self._prev = (left_position, right_position)
            self._stamp = now
            return self.state()
        d_left = left_position - self._prev[0]
        d_right = right_position - self._prev[1]
        self._prev = (left_position, right_position)
        dt = now - self._stamp
        self._stamp = now
        ds, dtheta = body_increment(
            d_left, d_right, wheel_radius=self.wheel_radius, wheel_separation=self.wheel_separation
        )
        if self.propagate:
            self._propagate(ds, dtheta, d_left, d_right)
        self.x, self.y, theta = integrate_arc(self.x, self.y, self.theta, ds, dtheta)
        self.theta = normalize_angle(theta)
        if dt > 0.0:
            self.v = ds / dt
            self.omega = dtheta / dt
        return self.state()

    def _propagate(self, ds: float, dtheta: float, d_left: float, d_right: float) -> None:
        mid = self.theta + 0.5 * dtheta
        c, s = math.cos(mid), math.sin(mid)
        f_pose = np.array([[1.0, 0.0, -ds * s], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
        # Jacobian of (Δx, Δy, Δθ) with respect to the wheel angle increments (left, right)
        r, sep = self.wheel_radius, self.wheel_separation
        dds = np.array([r / 2.0, r / 2.0])
        ddth = np.array([-r / sep, r / sep])
        f_wheels = np.vstack([c * dds - 0.5 * ds * s * ddth, s * dds + 0.5 * ds * c * ddth, ddth])
        k2 = self.encoder_noise**2
        wheel_cov = np.diag([k2 * abs(d_left), k2 * abs(d_right)])
        self._planar_cov = f_pose @ self._planar_cov @ f_pose.T + f_wheels @ wheel_cov @ f_wheels.T

    def state(self) -> OdometryState:
        """The current pose, twist and covariances."""
        if self.propagate:
            pose_cov = np.diag(self._pose_diag).astype(np.float64)
            idx = [0, 1, 5]
            pose_cov[np.ix_(idx, idx)] = self._planar_cov
        else:
            pose_cov = np.diag(self._pose_diag)
        return OdometryState(
            stamp=self._stamp,
            x=self.x,
            y=self.y,
            theta=self.theta,
            v=self.v,
            omega=self.omega,
            pose_covariance=pose_cov,
            twist_covariance=self._twist_cov.copy(),
        )
