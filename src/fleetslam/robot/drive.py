"""A modelled drive train for running the base controller without the simulator or hardware.

Each wheel is a first-order motor, J·dω/dt = clip(τ) − b·ω, integrated lazily up to the clock's time
whenever it is read or commanded, so it needs no thread of its own.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from fleetslam.robot.config import RobotConfig


class MotorModelDrive:
    """Two wheels with equivalent inertia ``inertia`` (kg·m²) and viscous ``damping`` (N·m·s/rad).

    Implements :class:`fleetslam.robot.interfaces.WheelInterface`.
    """

    def __init__(
        self,
        *,
        inertia: float = 0.05,
        damping: float = 0.05,
        torque_limit: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
        max_substep: float = 0.002,
    ) -> None:
        self.inertia = inertia
        self.damping = damping
        self.torque_limit = torque_limit
        self.clock = clock
        self.max_substep = max_substep
        self._time = clock()
        self._position = [0.0, 0.0]
        self._velocity = [0.0, 0.0]
        self._effort = [0.0, 0.0]

    @classmethod
    def from_config(cls, config: RobotConfig, clock: Callable[[], float] = time.monotonic) -> MotorModelDrive:
        """A drive whose torque limit is the robot's."""
        return cls(torque_limit=config.max_wheel_torque, clock=clock)

    def _advance(self) -> None:
        now = self.clock()
        remaining = now - self._time
        self._time = now
        while remaining > 0.0:
            h = min(remaining, self.max_substep)
            remaining -= h
            for i in range(2):
                accel = (self._effort[i] - self.damping * self._velocity[i]) / self.inertia
                self._position[i] += self._velocity[i] * h + 0.5 * accel * h * h
                self._velocity[i] += accel * h

    def wheel_positions(self) -> tuple[float, float]:
        self._advance()
        return self._position[0], self._position[1]

    def wheel_velocities(self) -> tuple[float, float]:
        self._advance()
        return self._velocity[0], self._velocity[1]

    def apply_wheel_efforts(self, left: float, right: float) -> None:
        self._advance()
        limit = self.torque_limit
        self._effort = [min(max(left, -limit), limit), min(max(right, -limit), limit)]
