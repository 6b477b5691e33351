"""The boundary between the base controller and a drive train (simulated or real).

The simulator implements :class:`WheelInterface` in-process; tests implement it with a small motor model.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class WheelInterface(Protocol):
    """Two driven wheels: read encoders, command motor torques."""

    def wheel_positions(self) -> tuple[float, float]:
        """(left, right) cumulative encoder angles in rad."""
        ...

    def wheel_velocities(self) -> tuple[float, float]:
        """(left, right) wheel angular speeds in rad/s."""
        ...

    def apply_wheel_efforts(self, left: float, right: float) -> None:
        """Command motor torques in N·m (the drive clips them to its own torque limit)."""
        ...
