"""The base controller (pure): velocity commands → limited twist → wheel set-points → PID torques.

Driven entirely by explicit ``now`` arguments (seconds) so it runs identically in simulated and wall time.
Safety: a command older than ``cmd_vel_timeout`` on arrival is dropped; every command holds only until its stamp
plus ``cmd_vel_timeout``, and the robot is *stopped* by then, not starting to brake: the set-point never exceeds what
the deceleration limit can bring to zero before that deadline (|v| ≤ max_deceleration · time left). So a lost link
stops the robot within ``cmd_vel_timeout`` of the last command at any speed, and a command stream must arrive faster
than ``cmd_vel_timeout`` minus the braking time to hold full speed (20 Hz commands, 1.5 m/s², 0.5 s and 50 Hz
control: up to 0.61 m/s). An engaged e-stop latches a zero set-point (wheels actively braked) until it is released.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from fleetslam.robot.config import RobotConfig
from fleetslam.robot.interfaces import WheelInterface
from fleetslam.robot.kinematics import wheel_speeds
from fleetslam.robot.limits import SpeedLimiter
from fleetslam.robot.odometry import Odometry, OdometryState
from fleetslam.robot.pid import Pid

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControllerOutput:
    """What one control step did."""

    odometry: OdometryState
    command: tuple[float, float]
    """The limited (v, ω) being tracked, m/s and rad/s."""
    setpoints: tuple[float, float]
    """(left, right) wheel speed set-points, rad/s."""
    efforts: tuple[float, float]
    """(left, right) torques applied, N·m."""
    joint_positions: tuple[float, float]
    """(left, right) wheel angles, rad."""
    joint_velocities: tuple[float, float]
    """(left, right) wheel speeds, rad/s."""
    estopped: bool
    timed_out: bool
    """No fresh command within ``cmd_vel_timeout``: braking to zero."""


class BaseController:
    """Differential-drive base controller. Construct from a :class:`RobotConfig` (defaults if None)."""

    def __init__(self, config: RobotConfig | None = None) -> None:
        self.config = config if config is not None else RobotConfig()
        cfg = self.config
        self.linear_limiter = SpeedLimiter(**cfg.linear.model_dump())
        self.angular_limiter = SpeedLimiter(**cfg.angular.model_dump())
        gains = cfg.wheel_pid
        self.wheel_pids = tuple(
            Pid(
                gains.kp,
                gains.ki,
                gains.kd,
                output_min=-cfg.max_wheel_torque,
                output_max=cfg.max_wheel_torque,
                derivative_filter_tau=gains.derivative_filter_tau,
                feedforward=gains.feedforward,
            )
            for _ in range(2)
        )
        self.odometry = Odometry(
            wheel_radius=cfg.wheel_radius,
            wheel_separation=cfg.wheel_separation,
            pose_covariance_diagonal=cfg.pose_covariance_diagonal,
            twist_covariance_diagonal=cfg.twist_covariance_diagonal,
            propagate=cfg.propagate_covariance,
            encoder_noise=cfg.encoder_noise_per_rad,
        )
        self._target = (0.0, 0.0)
        self._setpoints = (0.0, 0.0)
        self._last_stamp: float | None = None
        self._last_update: float | None = None
        self._estop = False
        self.dropped_commands = 0
        """Commands refused (stale, out of order, not finite, or during e-stop)."""

    @property
    def estopped(self) -> bool:
        """Whether the e-stop is engaged."""
        return self._estop

    def estop(self, engaged: bool) -> None:
        """Engage (latch zero) or release the e-stop; releasing needs a fresh command to move again."""
        if engaged and not self._estop:
            log.warning("e-stop engaged")
        elif not engaged and self._estop:
            log.info("e-stop released")
        self._estop = engaged
        self._target = (0.0, 0.0)
        if engaged:
            self._last_stamp = None
            # the integral built up while driving would fight the hold at zero speed
            for pid in self.wheel_pids:
                pid.reset()

    def command(self, v: float, omega: float, stamp: float, now: float) -> bool:
        """Offer a velocity command stamped ``stamp`` arriving at ``now``; returns whether it was accepted.

        A stamp in the future (clock skew) counts as ``now``, so it cannot extend the command's life.
        """
        stamp = min(stamp, now)
        accepted = (
            not self._estop
            and math.isfinite(v)
            and math.isfinite(omega)
            and now - stamp <= self.config.cmd_vel_timeout
            and (self._last_stamp is None or stamp >= self._last_stamp)
        )
        if not accepted:
            self.dropped_commands += 1
            log.debug("dropped command v=%s ω=%s stamp=%s at %s", v, omega, stamp, now)
            return False
        self._target = (v, omega)
        self._last_stamp = stamp
        return True

    def source_lost(self) -> None:
        """The commanding source is gone (its liveliness token was withdrawn, or its link cut): brake now, at the
        deceleration limits, instead of waiting for the command's deadline."""
        self._target = (0.0, 0.0)

    def timed_out(self, now: float) -> bool:
        """Whether the last accepted command is older than ``cmd_vel_timeout`` (or none came yet)."""
        return self._last_stamp is None or now - self._last_stamp > self.config.cmd_vel_timeout

    def _braking_envelope(self, now: float) -> tuple[float, float]:
        """The command, bounded so that the deceleration limits bring it to zero by the command's deadline."""
        v, omega = self._target
        # The set-point is zero two control periods early: the wheels follow it one or two steps behind.
        deadline = self.config.cmd_vel_timeout - 2.0 / self.config.control_rate
        left = 0.0 if self._last_stamp is None else max(self._last_stamp + deadline - now, 0.0)
        for limits, value in ((self.config.linear, v), (self.config.angular, omega)):
            if 0.0 < limits.max_deceleration < math.inf:
                bound = limits.max_deceleration * left
                value = min(max(value, -bound), bound)
            if limits is self.config.linear:
                v = value
            else:
                omega = value
        return v, omega

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> None:
        """Restart odometry at (x, y, θ)."""
        self.odometry.reset(x, y, theta)

    def update(self, now: float, wheels: WheelInterface) -> ControllerOutput:
        """One control step at ``now``: limit the command, track it with the wheel PIDs, integrate odometry."""
        cfg = self.config
        dt = 0.0 if self._last_update is None else max(now - self._last_update, 0.0)
        self._last_update = now
        timed_out = self.timed_out(now)
        if self._estop:
            self.linear_limiter.reset()
            self.angular_limiter.reset()
            v, omega = 0.0, 0.0
        else:
            target_v, target_omega = (0.0, 0.0) if timed_out else self._braking_envelope(now)
            v = self.linear_limiter.limit(target_v, dt)
            omega = self.angular_limiter.limit(target_omega, dt)
        setpoints = wheel_speeds(v, omega, wheel_radius=cfg.wheel_radius, wheel_separation=cfg.wheel_separation)
        positions = wheels.wheel_positions()
        velocities = wheels.wheel_velocities()
        ff = cfg.wheel_pid.acceleration_feedforward
        accel = [(new - old) / dt if dt > 0.0 else 0.0 for new, old in zip(setpoints, self._setpoints, strict=True)]
        self._setpoints = setpoints
        left_effort = self.wheel_pids[0].update(setpoints[0], velocities[0], dt, ff * accel[0])
        right_effort = self.wheel_pids[1].update(setpoints[1], velocities[1], dt, ff * accel[1])
        wheels.apply_wheel_efforts(left_effort, right_effort)
        odom = self.odometry.update(positions[0], positions[1], now)
        return ControllerOutput(
            odometry=odom,
            command=(v, omega),
            setpoints=setpoints,
            efforts=(left_effort, right_effort),
            joint_positions=(float(positions[0]), float(positions[1])),
            joint_velocities=(float(velocities[0]), float(velocities[1])),
            estopped=self._estop,
            timed_out=timed_out,
        )
