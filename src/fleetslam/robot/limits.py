"""Speed limiter: bounds a velocity channel's magnitude, acceleration, deceleration and jerk."""

from __future__ import annotations

import math


class SpeedLimiter:
    """Stateful limiter of one velocity channel (linear or angular).

    ``max_acceleration`` bounds growth of the speed magnitude, ``max_deceleration`` its decrease (braking);
    ``max_jerk`` (0 disables) bounds how fast the acceleration itself may change. Values ≤ 0 or inf disable
    the corresponding bound except ``max_velocity``, which must be positive.
    """

    def __init__(
        self,
        *,
        max_velocity: float,
        max_acceleration: float = math.inf,
        max_deceleration: float = math.inf,
        max_jerk: float = 0.0,
    ) -> None:
        if max_velocity <= 0.0:
            raise ValueError(f"max_velocity must be > 0, got {max_velocity}")
        self.max_velocity = max_velocity
        self.max_acceleration = max_acceleration if max_acceleration > 0.0 else math.inf
        self.max_deceleration = max_deceleration if max_deceleration > 0.0 else math.inf
        self.max_jerk = max_jerk if max_jerk > 0.0 else math.inf
        self.velocity = 0.0
        """The last limited velocity."""
        self.acceleration = 0.0
        """The last applied acceleration."""

    def reset(self, velocity: float = 0.0) -> None:
        """Restart from ``velocity`` with zero acceleration."""
        self.velocity = velocity
        self.acceleration = 0.0

    def limit(self, target: float, dt: float) -> float:
        """Move from the last velocity toward ``target`` over ``dt`` seconds within the limits."""
        target = min(max(target, -self.max_velocity), self.max_velocity)
        if dt <= 0.0:
            return self.velocity
        current = self.velocity
        remaining = target - current
        wanted = remaining / dt
        if math.isfinite(self.max_jerk):
            # approach the target along a jerk-bounded ramp so the acceleration is back at zero on arrival
            # (largest a whose discrete ramp-down, a²/2j + a·dt/2, still fits in the remaining change)
            jerk = self.max_jerk
            ramp = jerk * (math.sqrt(0.25 * dt * dt + 2.0 * abs(remaining) / jerk) - 0.5 * dt)
            wanted = math.copysign(min(abs(wanted), ramp), remaining)
        braking = current * wanted < 0.0
        bound = self.max_deceleration if braking else self.max_acceleration
        accel = min(max(wanted, -bound), bound)
        if math.isfinite(self.max_jerk):
            step = self.max_jerk * dt
            accel = min(max(accel, self.acceleration - step), self.acceleration + step)
        new = current + accel * dt
        # a jerk-bounded acceleration must not carry the velocity past the target
        if (target - current) * (target - new) < 0.0 or (target == current):
            new = target
            accel = (new - current) / dt
        if abs(new) < 1e-12:
            new = 0.0
        if braking and current * new < 0.0:
            # braking stops at zero within this step; reversing starts next step under the accel bound
            new = 0.0
            accel = -current / dt
        self.velocity = min(max(new, -self.max_velocity), self.max_velocity)
        self.acceleration = accel
        return self.velocity
