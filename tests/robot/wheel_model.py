"""A two-wheel drive model used by the tests as the real drive behind WheelInterface.

Each wheel is a first-order motor: J·dω/dt = clip(τ) − b·ω, integrated with small sub-steps.
"""

from __future__ import annotations

import numpy as np


class MotorWheels:
    """Two independent wheels with inertia ``inertia`` (kg·m²), viscous friction ``damping`` (N·m·s/rad)."""

    def __init__(
        self, *, inertia: float = 0.05, damping: float = 0.05, torque_limit: float = 2.0, substeps: int = 10
    ) -> None:
        self.inertia = inertia
        self.damping = damping
        self.torque_limit = torque_limit
        self.substeps = substeps
        self.position = np.zeros(2)
        self.velocity = np.zeros(2)
        self.effort = np.zeros(2)

    def wheel_positions(self) -> tuple[float, float]:
        return float(self.position[0]), float(self.position[1])

    def wheel_velocities(self) -> tuple[float, float]:
        return float(self.velocity[0]), float(self.velocity[1])

    def apply_wheel_efforts(self, left: float, right: float) -> None:
        self.effort = np.clip([left, right], -self.torque_limit, self.torque_limit)

    def advance(self, dt: float) -> None:
        h = dt / self.substeps
        for _ in range(self.substeps):
            accel = (self.effort - self.damping * self.velocity) / self.inertia
            self.position += self.velocity * h + 0.5 * accel * h * h
            self.velocity += accel * h
