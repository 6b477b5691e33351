"""Point-to-plane alignment of a depth image to a keyframe's surface: the geometric term of RGB-D odometry (pure).

Sparse features alone leave a pose poorly determined where the scene is poor in texture (a grey wall, a plain
floor, a small image): twenty matched corners fix a pose to centimetres, and a keyframe made there carries that
error into the map. The depth image still sees the room's geometry everywhere. As in KinectFusion's ICP and the
hybrid RGB-D odometry of Open3D or DVO-SLAM, the frame's depth samples are associated by projection with the last
keyframe's surface and each contributes the residual

    rᵢ = nᵢᵀ (T_wc · pᵢ − qᵢ) / σ(zᵢ)

(qᵢ, nᵢ: the keyframe's vertex and normal where pᵢ projects; σ(z) the sensor's depth noise). The residuals and
their Jacobian in the left perturbation of ``T_camera_world`` feed the same Gauss–Newton as the reprojection errors
(:mod:`fleetslam.slam.pose_refinement`), so where the features are many they dominate, and where they are few
the floor, walls and objects hold the pose. Association is re-done at every iteration (projective, one lookup per
sample: cheap at a few thousand samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.slam.features import import_cv2


def sample_stride(intrinsics: Intrinsics, samples: int) -> int:
    """The pixel stride that leaves about ``samples`` depth samples in an image (at least 1)."""
    return max(1, round(float(np.sqrt(intrinsics.width * intrinsics.height / max(samples, 1)))))


def depth_samples(
    depth: NDArray[np.float32], intrinsics: Intrinsics, stride: int, min_depth: float, max_depth: float
) -> NDArray[np.float64]:
    """(N, 3) camera-frame points of every ``stride``-th pixel with a valid depth (half a stride in from the
    border, so they interleave with the keyframe's grid)."""
    offset = stride // 2
    z = np.asarray(depth[offset::stride, offset::stride], np.float64)
    v, u = np.mgrid[offset : depth.shape[0] : stride, offset : depth.shape[1] : stride]
    ok = np.isfinite(z) & (z > min_depth) & (z < max_depth)
    z, u, v = z[ok], u[ok], v[ok]
    return np.stack([(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z], axis=1)


@dataclass(frozen=True)
class KeyframeSurface:
    """A keyframe's depth as a grid of vertices and normals in its camera frame (every ``stride``-th pixel)."""

    vertices: NDArray[np.float64]
    """(h, w, 3) camera-frame points."""
    normals: NDArray[np.float64]
    """(h, w, 3) unit normals facing the camera; rows of zeros where unknown."""
    valid: NDArray[np.bool_]
    """(h, w) where both are known."""
    stride: int
    intrinsics: Intrinsics

    @classmethod
    def from_depth(
        cls,
        depth: NDArray[np.float32],
        intrinsics: Intrinsics,
        stride: int,
        min_depth: float,
        max_depth: float,
        max_step: float = 0.05,
    ) -> KeyframeSurface:
        """Vertices on the stride grid and normals from their neighbours (central differences), both from the
        depth averaged over a stride around each pixel: a depth camera's noise (centimetres at 3 m) over a
        stride's baseline (5 cm at 3 m, 320 px wide) would tilt single-pixel normals by tens of degrees. A normal
        needs its four neighbours, and the raw depth there, within ``max_step`` + 5 % of the depth (none across a
        depth edge)."""
        cv2 = import_cv2()
        raw = np.asarray(depth, np.float32)
        has_raw = np.isfinite(raw) & (raw > min_depth) & (raw < max_depth)
        filled = np.where(has_raw, raw, 0.0).astype(np.float32)
        size = (2 * stride + 1, 2 * stride + 1)
        total = cv2.boxFilter(filled, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
        count = cv2.boxFilter(has_raw.astype(np.float32), -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
        smooth = np.where(count > 0, total / np.maximum(count, 1.0), 0.0)
        z_raw = np.where(has_raw, raw, 0.0)[::stride, ::stride].astype(np.float64)
        z = smooth[::stride, ::stride].astype(np.float64)
        has = has_raw[::stride, ::stride] & (np.abs(z - z_raw) < max_step + 0.05 * z_raw)
        z = np.where(has, z, 0.0)
        v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
        vertices = np.stack([(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z], -1)
        normals = np.zeros_like(vertices)
        ok = np.zeros(z.shape, bool)
        if z.shape[0] >= 3 and z.shape[1] >= 3:
            dx = vertices[1:-1, 2:] - vertices[1:-1, :-2]
            dy = vertices[2:, 1:-1] - vertices[:-2, 1:-1]
            n = np.cross(dx, dy)
            length = np.linalg.norm(n, axis=-1)
            centre = z_raw[1:-1, 1:-1]
            bound = max_step + 0.05 * centre
            smooth_here = has[1:-1, 1:-1] & (length > 1e-12)
            for neighbour in (z_raw[1:-1, 2:], z_raw[1:-1, :-2], z_raw[2:, 1:-1], z_raw[:-2, 1:-1]):
                smooth_here &= (neighbour > 0) & (np.abs(neighbour - centre) < bound)
            for known in (has[1:-1, 2:], has[1:-1, :-2], has[2:, 1:-1], has[:-2, 1:-1]):
                smooth_here &= known
            n = n / np.maximum(length, 1e-12)[..., None]
            # Face the camera (the normal and the viewing ray point against each other).
            n = np.where((np.einsum("hwk,hwk->hw", n, vertices[1:-1, 1:-1]) > 0)[..., None], -n, n)
            normals[1:-1, 1:-1] = np.where(smooth_here[..., None], n, 0.0)
            ok[1:-1, 1:-1] = smooth_here
        return cls(vertices, normals, ok, stride, intrinsics)


@dataclass(frozen=True)
class SurfaceTerm:
    """The point-to-plane residuals of a frame's depth samples against a keyframe's surface."""

    surface: KeyframeSurface
    keyframe_pose: NDArray[np.float64]
    """``T_world_camera`` of the keyframe."""
    points: NDArray[np.float64]
    """(N, 3) the frame's depth samples in its camera frame."""
    depth_noise: float
    """σ(z) = depth_noise·z² + 1 mm per sample, as the sensor's depth."""
    std_scale: float = 1.0
    """Multiplies σ: neighbouring samples' errors are correlated (the sensor's noise is not white over a few
    pixels, and the surface is sampled), so they are worth less than independent measurements."""
    max_distance: float = 0.05
    """Pairs farther apart than this (metres, before the plane) are not the same surface."""
    huber: float = 2.0
    """Huber threshold in standard deviations: a sample on a surface that moved or was wrongly associated pulls
    no harder than this."""

    def linearize(self, T_camera_world: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Whitened residuals (m,) and their Jacobian (m, 6) in the left perturbation (translation, rotation) of
        ``T_camera_world``, over the samples that found their surface."""
        # The samples in the keyframe's camera frame (T_key_camera = T_key_world · T_world_camera), and where they
        # fall on its grid.
        key_rotation = self.keyframe_pose[:3, :3].T @ T_camera_world[:3, :3].T
        key_translation = self.keyframe_pose[:3, :3].T @ (
            T_camera_world[:3, :3].T @ -T_camera_world[:3, 3] - self.keyframe_pose[:3, 3]
        )
        p_key = self.points @ key_rotation.T + key_translation
        k, s = self.surface.intrinsics, self.surface.stride
        z = p_key[:, 2]
        front = z > 1e-6
        inverse_z = 1.0 / np.where(front, z, 1.0)
        col = np.rint((k.fx * p_key[:, 0] * inverse_z + k.cx) / s).astype(np.intp)
        row = np.rint((k.fy * p_key[:, 1] * inverse_z + k.cy) / s).astype(np.intp)
        h, w = self.surface.valid.shape
        idx = np.flatnonzero(front & (col >= 0) & (col < w) & (row >= 0) & (row < h))
        cell = row[idx] * w + col[idx]
        found = self.surface.valid.reshape(-1)[cell]
        idx, cell = idx[found], cell[found]
        difference = p_key[idx] - self.surface.vertices.reshape(-1, 3)[cell]
        close = np.einsum("nk,nk->n", difference, difference) < self.max_distance**2
        idx, cell, difference = idx[close], cell[close], difference[close]
        n = self.surface.normals.reshape(-1, 3)[cell]
        p = self.points[idx]
        sigma = self.std_scale * (self.depth_noise * p[:, 2] ** 2 + 1e-3)
        residual = np.einsum("nk,nk->n", n, difference) / sigma
        # The normal in this frame's camera axes: r = nᵀ(R_kc·p + t_kc − q), p moving as T_cw is perturbed on the
        # left (∂p_world/∂δt = −R_wc, ∂p_world/∂δr = R_wc·[p]×).
        m = (n @ key_rotation) / sigma[:, None]
        jacobian = np.empty((len(idx), 6))
        jacobian[:, :3] = -m
        jacobian[:, 3:] = np.cross(m, p)
        return residual, jacobian
