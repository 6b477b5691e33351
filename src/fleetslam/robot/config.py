"""Typed configuration of the robot base: geometry, limits, wheel PID, odometry noise, teleop."""

from __future__ import annotations

from pydantic import Field

from fleetslam.config import ConfigModel


class PidGains(ConfigModel):
    """Gains and limits of one wheel velocity loop (set-point rad/s, output torque N·m)."""

    kp: float = 0.8
    """Proportional gain, N·m per rad/s of velocity error."""
    ki: float = 8.0
    """Integral gain, N·m per rad of accumulated velocity error."""
    kd: float = 0.0
    """Derivative gain on the (filtered) measurement, N·m per rad/s²."""
    derivative_filter_tau: float = 0.02
    """Time constant of the first-order low-pass filter on the derivative term, s."""
    feedforward: float = 0.0
    """Feed-forward torque per rad/s of set-point (viscous friction compensation), N·m·s/rad."""
    acceleration_feedforward: float = 0.03
    """Feed-forward torque per rad/s² of set-point acceleration (the wheel's share of the robot's inertia),
    N·m·s²/rad; it keeps the integral from winding up on speed ramps, so stops do not undershoot."""


class SpeedLimits(ConfigModel):
    """Limits of one velocity channel (linear m/s or angular rad/s), like diff_drive_controller's."""

    max_velocity: float = 0.8
    """Largest magnitude of the velocity."""
    max_acceleration: float = 0.8
    """Largest rate of increase of the speed magnitude, per s."""
    max_deceleration: float = 1.5
    """Largest rate of decrease of the speed magnitude (braking), per s."""
    max_jerk: float = 0.0
    """Largest rate of change of the acceleration, per s²; 0 disables the jerk limit."""


def _angular_limits() -> SpeedLimits:
    return SpeedLimits(max_velocity=1.5, max_acceleration=3.0, max_deceleration=4.0, max_jerk=0.0)


class RobotConfig(ConfigModel):
    """A TurtleBot-like differential-drive inspection base. The simulator builds its model from these."""

    wheel_radius: float = Field(default=0.075, gt=0.0)
    """Wheel radius r, m."""
    wheel_separation: float = Field(default=0.40, gt=0.0)
    """Distance L between the two wheel contact points, m."""
    max_wheel_torque: float = Field(default=2.0, gt=0.0)
    """Largest motor torque the controller commands, N·m (the drive may clip further)."""
    linear: SpeedLimits = SpeedLimits()
    """Limits of the linear velocity v (m/s, m/s², m/s³)."""
    angular: SpeedLimits = Field(default_factory=_angular_limits)
    """Limits of the angular velocity ω (rad/s, rad/s², rad/s³)."""
    wheel_pid: PidGains = PidGains()
    """Velocity loop of each wheel."""
    cmd_vel_timeout: float = Field(default=0.5, gt=0.0)
    """A command older than this on arrival is dropped; without a fresh one for this long the base brakes, s."""
    control_rate: float = Field(default=50.0, gt=0.0)
    """Rate of the wheel control loop, Hz."""
    odom_rate: float = Field(default=50.0, gt=0.0)
    """Rate at which odometry, joint states and tf are published, Hz."""
    pose_covariance_diagonal: tuple[float, float, float, float, float, float] = (
        0.001,
        0.001,
        1e6,
        1e6,
        1e6,
        0.01,
    )
    """Diagonal of the pose covariance (x, y, z, roll, pitch, yaw); large values mark unobserved axes."""
    twist_covariance_diagonal: tuple[float, float, float, float, float, float] = (
        0.001,
        0.001,
        1e6,
        1e6,
        1e6,
        0.01,
    )
    """Diagonal of the twist covariance (vx, vy, vz, wx, wy, wz)."""
    propagate_covariance: bool = False
    """Grow the pose covariance from encoder noise instead of using the fixed diagonal."""
    encoder_noise_per_rad: float = 0.01
    """k in σ²(Δφ) = k²·|Δφ| for the angle increment of each wheel (propagated covariance), rad/√rad."""
    odom_frame: str = "odom"
    """Frame of the odometry pose."""
    base_frame: str = "base_link"
    """Frame of the robot body."""
    left_wheel_joint: str = "left_wheel_joint"
    """Joint name of the left wheel in joint_states."""
    right_wheel_joint: str = "right_wheel_joint"
    """Joint name of the right wheel in joint_states."""
    publish_tf: bool = True
    """Publish odom → base_link on tf."""
