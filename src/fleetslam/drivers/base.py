"""What a live RGB-D camera driver is: the seam between a device and the middleware (no middleware, no simulator).

A driver yields :class:`~fleetslam.datasets.base.RGBDFrame` objects as the device delivers them: ``rgb (H, W, 3)``
uint8 in RGB order and ``depth (H, W)`` float32 metres registered to it (0 = invalid), stamped in seconds on the
clock the rest of the robot uses. :class:`~fleetslam.drivers.node.CameraNode` publishes them; an offline
:class:`~fleetslam.datasets.base.RGBDSource` (a TUM folder, a recording) is a driver too, once it has ``close``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from fleetslam.datasets.base import Intrinsics, RGBDFrame


@runtime_checkable
class CameraDriver(Protocol):
    """A live RGB-D device."""

    intrinsics: Intrinsics
    """Pinhole intrinsics of the depth-registered colour image."""
    name: str
    """Short name for logs."""

    def __iter__(self) -> Iterator[RGBDFrame]:
        """Frames as they come (blocking until the next one); ends when the device stops."""
        ...

    def close(self) -> None:
        """Release the device; may be called more than once."""
        ...
