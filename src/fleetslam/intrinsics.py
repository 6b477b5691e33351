"""Pinhole camera intrinsics (OpenCV convention), shared by datasets, the simulator, SLAM and the messages.

Pixel centres sit at integer coordinates; the optical frame is the ROS/OpenCV one (x right, y down, z forward).
:func:`fleetslam.msg.conversions.camera_info_msg` and :func:`~fleetslam.msg.conversions.intrinsics_from_camera_info`
turn it into a ``sensor_msgs/CameraInfo`` and back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Intrinsics", "pinhole_problem"]


def pinhole_problem(fx: float, fy: float, cx: float, cy: float) -> str | None:
    """What makes these values not a pinhole camera, or None. Received intrinsics are checked with it before anything
    is back-projected: a zero focal length makes every point infinite, a negative one mirrors them."""
    values = f"fx={fx}, fy={fy}, cx={cx}, cy={cy}"
    if not np.isfinite([fx, fy, cx, cy]).all():
        return f"{values}: not all finite"
    if fx <= 0 or fy <= 0:
        return f"{values}: focal lengths must be positive"
    return None


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics with pixel centres at integer coordinates (OpenCV convention)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 640
    height: int = 480

    @classmethod
    def from_focal(cls, focal_length: float, width: int, height: int) -> Intrinsics:
        """Square pixels, principal point at the image centre."""
        return cls(focal_length, focal_length, (width - 1) / 2.0, (height - 1) / 2.0, width, height)

    @property
    def K(self) -> NDArray[np.float64]:
        """3×3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view, degrees."""
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.fy)))

    @property
    def fovx_deg(self) -> float:
        """Horizontal field of view, degrees."""
        return math.degrees(2.0 * math.atan(self.width / (2.0 * self.fx)))

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same optics at another resolution."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, width, height
        )

    def backproject_image(self, depth: NDArray[np.floating]) -> NDArray[np.float64]:
        """(H, W, 3) points in the optical frame for every pixel (invalid depth gives z = 0 points)."""
        h, w = depth.shape
        u = np.arange(w, dtype=np.float64)[None, :]
        v = np.arange(h, dtype=np.float64)[:, None]
        z = depth.astype(np.float64)
        return np.stack(((u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z), axis=-1)

    def backproject(self, depth: NDArray[np.floating]) -> NDArray[np.float64]:
        """(N, 3) points in the optical frame of the valid (finite, > 0) pixels, row-major order."""
        points = self.backproject_image(depth)
        valid = np.isfinite(depth) & (depth > 0)
        return points[valid]
