"""A PID loop with output limits, anti-windup by conditional integration, filtered derivative on measurement."""

from __future__ import annotations

import math


class Pid:
    """u = feedforward·r + kp·e + ki·∫e + kd·d/dt(−y), clipped to [output_min, output_max].

    The derivative acts on the measurement, not the error, so set-point steps cause no kick; it passes
    through a first-order low-pass filter of time constant ``derivative_filter_tau``. The integral only
    accumulates while that does not push a saturated output further into saturation (clamping anti-windup).
    """

    def __init__(
        self,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        *,
        output_min: float = -math.inf,
        output_max: float = math.inf,
        derivative_filter_tau: float = 0.0,
        feedforward: float = 0.0,
    ) -> None:
        if output_min > output_max:
            raise ValueError(f"output_min {output_min} > output_max {output_max}")
        self.kp, self.ki, self.kd = kp, ki, kd
        self.output_min, self.output_max = output_min, output_max
        self.derivative_filter_tau = derivative_filter_tau
        self.feedforward = feedforward
        self.integral = 0.0
        """The integral term's contribution to the output (ki·∫e), in output units."""
        self._derivative = 0.0
        self._prev_measurement: float | None = None
        self.saturated = False
        """Whether the last output was clipped."""

    def reset(self) -> None:
        """Forget the integral, the derivative filter and the previous measurement."""
        self.integral = 0.0
        self._derivative = 0.0
        self._prev_measurement = None
        self.saturated = False

    def update(self, setpoint: float, measurement: float, dt: float, feedforward: float = 0.0) -> float:
        """One step of the loop, ``dt`` seconds after the previous one; returns the clipped output.

        ``feedforward`` is added to the output before clipping (e.g. inertia × set-point acceleration), so
        the anti-windup sees it too.
        """
        error = setpoint - measurement
        if dt > 0.0 and self._prev_measurement is not None:
            raw = -(measurement - self._prev_measurement) / dt
            alpha = self.derivative_filter_tau / (self.derivative_filter_tau + dt)
            self._derivative = alpha * self._derivative + (1.0 - alpha) * raw
        self._prev_measurement = measurement
        base = feedforward + self.feedforward * setpoint + self.kp * error + self.kd * self._derivative
        candidate = self.integral + self.ki * error * dt if dt > 0.0 else self.integral
        unclipped = base + candidate
        pushes_up = unclipped > self.output_max and error > 0.0
        pushes_down = unclipped < self.output_min and error < 0.0
        if not (pushes_up or pushes_down):
            self.integral = candidate
        output = base + self.integral
        clipped = min(max(output, self.output_min), self.output_max)
        self.saturated = clipped != output
        return clipped
