"""The simulated camera: its intrinsics from the configuration and a Kinect v1-like depth sensor model (pure:
arrays in, arrays out).

Depth images are z-depth along the optical axis in metres, 0 where invalid. The optical frame is the ROS/
OpenCV one: x right, y down, z forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.intrinsics import Intrinsics
from fleetslam.sim.config import CameraConfig

CameraIntrinsics = Intrinsics
"""The simulator's name for :class:`fleetslam.intrinsics.Intrinsics` (the same class)."""


@dataclass(frozen=True)
class KinectModel:
    """Kinect v1 depth errors applied to a perfect z-depth image.

    - range limits: outside [min_depth, max_depth] → invalid;
    - axial noise with total σ(z) = k·z², of which disparity quantisation (``disparity_step`` pixels with
      focal ``disparity_focal`` and ``baseline``) contributes step²/12 in disparity space — on average over where
      the true disparity falls between two levels; a surface whose disparity sits exactly on a level gets about
      6 % less (the quantisation's share is then smaller than step²/12);
    - invalid at grazing incidence (normal vs ray > ``max_incidence_deg``, normals from depth gradients)
      and on both sides of depth discontinuities larger than ``edge_jump``·z.
    """

    intrinsics: Intrinsics
    min_depth: float = 0.5
    max_depth: float = 4.5
    noise_coefficient: float = 1.43e-3
    disparity_focal: float = 580.0
    baseline: float = 0.075
    disparity_step: float = 0.125
    max_incidence_deg: float = 80.0
    edge_jump: float = 0.05

    def quantisation_step(self, z: NDArray[np.floating] | float) -> NDArray[np.float64]:
        """Depth step between adjacent disparity levels at depth z, m."""
        z_arr = np.asarray(z, dtype=np.float64)
        return z_arr**2 * self.disparity_step / (self.disparity_focal * self.baseline)

    def invalid_mask(self, depth_true: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Pixels the sensor cannot measure: out of range, grazing incidence, next to depth edges."""
        z = depth_true.astype(np.float64)
        finite = np.isfinite(z) & (z > 0)
        z = np.where(finite, z, 0.0)
        invalid = ~finite | (z < self.min_depth) | (z > self.max_depth)
        if self.edge_jump > 0:
            jump = np.zeros(z.shape, dtype=bool)
            dx = np.abs(np.diff(z, axis=1)) > self.edge_jump * np.minimum(z[:, 1:], z[:, :-1]).clip(1e-6)
            dy = np.abs(np.diff(z, axis=0)) > self.edge_jump * np.minimum(z[1:, :], z[:-1, :]).clip(1e-6)
            jump[:, 1:] |= dx
            jump[:, :-1] |= dx
            jump[1:, :] |= dy
            jump[:-1, :] |= dy
            invalid |= jump & finite
        if self.max_incidence_deg < 90.0:
            invalid |= self._grazing(z) & finite
        return invalid

    def _grazing(self, z: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Pixels whose surface normal (from depth gradients) is more than the limit away from the ray.

        With P = z·r, r = ((u-cx)/fx, (v-cy)/fy, 1), the normal ∂P/∂u × ∂P/∂v is (-a, -b, a·rx + b·ry + c) with
        a = z·z_u/fy, b = z·z_v/fx, c = z²/(fx·fy), and n·r = c; so cos(incidence) = c / (|n|·|r|), compared
        squared to avoid square roots.
        """
        k = self.intrinsics
        zf = z.astype(np.float32)
        z_v, z_u = np.gradient(zf)
        rx = ((np.arange(z.shape[1], dtype=np.float32) - k.cx) / k.fx)[None, :]
        ry = ((np.arange(z.shape[0], dtype=np.float32) - k.cy) / k.fy)[:, None]
        a = zf * z_u / np.float32(k.fy)
        b = zf * z_v / np.float32(k.fx)
        c = zf * zf / np.float32(k.fx * k.fy)
        nz = a * rx + b * ry + c
        n2 = a * a + b * b + nz * nz
        r2 = rx * rx + ry * ry + 1.0
        cos_limit = np.float32(math.cos(math.radians(self.max_incidence_deg)))
        return (c * c < cos_limit * cos_limit * n2 * r2) & (c > 0)

    def apply(self, depth_true: NDArray[np.floating], rng: np.random.Generator) -> NDArray[np.float32]:
        """A measured depth image (float32 m, 0 = invalid) from the true z-depth image."""
        invalid = self.invalid_mask(depth_true)
        z = np.where(invalid, np.float32(1.0), depth_true).astype(np.float32)
        fb = self.disparity_focal * self.baseline
        if self.disparity_step > 0:
            # σ_z = k·z² is a constant σ_d = k·fb in disparity d = fb/z. Gaussian noise is added there and then
            # rounded to the step; its share is reduced so Gaussian + uniform rounding (step²/12) total k·fb.
            sigma_d = math.sqrt(max((self.noise_coefficient * fb) ** 2 - self.disparity_step**2 / 12.0, 0.0))
            noisy = np.float32(fb) / z + rng.standard_normal(z.shape, dtype=np.float32) * np.float32(sigma_d)
            step = np.float32(self.disparity_step)
            quantised = np.maximum(np.round(noisy / step), 1.0) * step
            measured = np.float32(fb) / quantised
        else:
            noise = rng.standard_normal(z.shape, dtype=np.float32)
            measured = z + noise * np.float32(self.noise_coefficient) * z * z
        measured[invalid] = 0.0
        measured[(measured < self.min_depth) | (measured > self.max_depth)] = 0.0
        return measured.astype(np.float32)


def intrinsics_from_config(config: CameraConfig, width: int | None = None, height: int | None = None) -> Intrinsics:
    """Intrinsics of the configured camera at its resolution (or at ``width`` × ``height``)."""
    w = config.width if width is None else width
    h = config.height if height is None else height
    return Intrinsics.from_focal(config.focal_length * w / 640.0, w, h)


def kinect_from_config(config: CameraConfig, intrinsics: Intrinsics) -> KinectModel:
    """The sensor model of the configured camera."""
    return KinectModel(
        intrinsics,
        min_depth=config.min_depth,
        max_depth=config.max_depth,
        noise_coefficient=config.noise_coefficient,
        disparity_focal=config.disparity_focal_length,
        baseline=config.baseline,
        disparity_step=config.disparity_step,
        max_incidence_deg=config.max_incidence_deg,
        edge_jump=config.edge_jump,
    )
