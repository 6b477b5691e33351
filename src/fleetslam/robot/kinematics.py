"""Differential-drive kinematics: body twist (v, ω) ↔ wheel angular speeds.

With wheel radius r and wheel separation L, the right and left wheel speeds (rad/s) are
``ω_R = (2v + ωL) / (2r)`` and ``ω_L = (2v − ωL) / (2r)``; conversely ``v = r(ω_R + ω_L)/2`` and
``ω = r(ω_R − ω_L)/L``.
"""

from __future__ import annotations


def wheel_speeds(v: float, omega: float, *, wheel_radius: float, wheel_separation: float) -> tuple[float, float]:
    """(left, right) wheel angular speeds in rad/s for body velocity v (m/s) and yaw rate ω (rad/s)."""
    left = (2.0 * v - omega * wheel_separation) / (2.0 * wheel_radius)
    right = (2.0 * v + omega * wheel_separation) / (2.0 * wheel_radius)
    return left, right


def body_twist(left: float, right: float, *, wheel_radius: float, wheel_separation: float) -> tuple[float, float]:
    """(v, ω) of the body for (left, right) wheel angular speeds in rad/s (forward kinematics)."""
    v = wheel_radius * (right + left) / 2.0
    omega = wheel_radius * (right - left) / wheel_separation
    return v, omega


def body_increment(
    d_left: float, d_right: float, *, wheel_radius: float, wheel_separation: float
) -> tuple[float, float]:
    """(Δs, Δθ): arc length and heading change for wheel angle increments (rad)."""
    return body_twist(d_left, d_right, wheel_radius=wheel_radius, wheel_separation=wheel_separation)
