"""Photometric alignment of a frame to a keyframe's image: the direct term of RGB-D odometry (pure).

Corners are what ORB finds, and a small image of a plain hall has few of them: thirty matched keypoints leave the
pose to a few centimetres, and the point-to-plane term (:mod:`fleetslam.slam.surface_alignment`) does not see
along a flat floor or wall. The image still has edges there: tile joints, shelf rails, a stripe on a tank. As in
DVO-SLAM and Open3D's hybrid odometry, pixels of the newest keyframe where the intensity changes (the strongest
gradient of each block, with a measured depth) are moved into the frame by the pose and compared with the
frame's intensity there:

    rᵢ = (I_frame(π(T_cw · T_wk · Xᵢ)) − I_key(uᵢ)) / σ_I

Their Jacobian in the left perturbation of ``T_camera_world`` (the image gradient times the projection's) joins
the same Gauss–Newton as the reprojection errors and the surface term. Both images are smoothed first, which
widens the basin to a few pixels: the features and the motion prediction start the pose well inside it. The term
works on the image pyramid's level nearest a 320-pixel width (:func:`pyramid_level`): at any resolution it then
costs the same and sees edges at the same scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.slam.features import import_cv2


def pyramid_level(width: int, target_width: int = 320) -> int:
    """How many halvings bring an image ``width`` pixels wide nearest to ``target_width`` without going below it
    (640 → 1, 320 → 0, 1280 → 2, 480 → 0)."""
    return max(0, math.floor(math.log2(max(width, 1) / target_width))) if width > target_width else 0


def level_intrinsics(intrinsics: Intrinsics, level: int) -> Intrinsics:
    """The intrinsics of a pyramid level made by ``cv2.pyrDown`` (pixel i of a level sits on pixel 2i of the one
    below, so the principal point halves with the focal length)."""
    scale = 0.5**level
    width, height = intrinsics.width, intrinsics.height
    for _ in range(level):
        width, height = (width + 1) // 2, (height + 1) // 2
    return Intrinsics(intrinsics.fx * scale, intrinsics.fy * scale, intrinsics.cx * scale, intrinsics.cy * scale,
                      width, height)  # fmt: skip


@dataclass(frozen=True)
class FrameIntensity:
    """A frame's smoothed intensity and its gradients on one pyramid level (float32, grey levels and grey levels
    per pixel of the level)."""

    image: NDArray[np.float32]
    gradient_u: NDArray[np.float32]
    gradient_v: NDArray[np.float32]
    intrinsics: Intrinsics
    """The level's intrinsics."""
    level: int = 0

    @classmethod
    def from_gray(
        cls, gray: NDArray[np.uint8], intrinsics: Intrinsics, blur_px: float, level: int = 0
    ) -> FrameIntensity:
        """Halved ``level`` times (``cv2.pyrDown``), smoothed by a Gaussian of ``blur_px`` (σ, pixels of the level);
        gradients by central differences (Scharr's are sharper but the blur has already set the scale)."""
        cv2 = import_cv2()
        image = np.asarray(gray, np.float32)
        for _ in range(level):
            image = cv2.pyrDown(image)
        if blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        gradient_u = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
        gradient_v = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
        return cls(image, gradient_u, gradient_v, level_intrinsics(intrinsics, level), level)


@dataclass(frozen=True)
class KeyframeIntensity:
    """The keyframe pixels the term compares: their 3D points in its camera frame and their intensities."""

    points: NDArray[np.float64]
    """(N, 3) camera-frame points (from the keyframe's depth)."""
    intensities: NDArray[np.float64]
    """(N,) their smoothed intensities."""

    @classmethod
    def select(
        cls,
        intensity: FrameIntensity,
        depth: NDArray[np.float32],
        block: int,
        min_gradient: float,
        min_depth: float,
        max_depth: float,
    ) -> KeyframeIntensity:
        """The strongest gradient of every ``block`` × ``block`` pixels of the level (DSO's selection: spread over
        the image, not bunched on the few strongest edges) where it is at least ``min_gradient`` and the depth is
        valid; a pixel next to a depth edge is left out (its depth may belong to the other surface). ``depth`` is
        the full image's; a level's pixel takes the depth of the pixel it sits on."""
        cv2 = import_cv2()
        intrinsics = intensity.intrinsics
        magnitude = np.hypot(intensity.gradient_u, intensity.gradient_v)
        step = 2**intensity.level
        raw = np.nan_to_num(np.asarray(depth, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        valid = (raw > min_depth) & (raw < max_depth)
        # A depth edge: the depth changes by more than 5 % within one pixel.
        spread = cv2.dilate(raw, np.ones((3, 3), np.uint8)) - cv2.erode(raw, np.ones((3, 3), np.uint8))
        usable = (valid & (spread <= 0.05 * raw))[::step, ::step][: magnitude.shape[0], : magnitude.shape[1]]
        raw = raw[::step, ::step][: magnitude.shape[0], : magnitude.shape[1]]
        usable[:2, :] = usable[-2:, :] = usable[:, :2] = usable[:, -2:] = False
        score = np.where(usable, magnitude, 0.0)
        h, w = score.shape
        rows, cols = h // block, w // block
        if rows == 0 or cols == 0:
            return cls(np.zeros((0, 3)), np.zeros(0))
        tiles = score[: rows * block, : cols * block].reshape(rows, block, cols, block).transpose(0, 2, 1, 3)
        best = tiles.reshape(rows, cols, block * block).argmax(axis=2)
        v = (np.arange(rows)[:, None] * block + best // block).reshape(-1)
        u = (np.arange(cols)[None, :] * block + best % block).reshape(-1)
        keep = score[v, u] >= min_gradient
        u, v = u[keep], v[keep]
        z = raw[v, u].astype(np.float64)
        points = np.stack([(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z], 1)
        return cls(points, intensity.image[v, u].astype(np.float64))


def _bilinear(image: NDArray[np.float32], u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Values of ``image`` at sub-pixel positions inside it (callers keep them one pixel in from the border)."""
    u0, v0 = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
    fu, fv = u - u0, v - v0
    top = image[v0, u0] * (1 - fu) + image[v0, u0 + 1] * fu
    bottom = image[v0 + 1, u0] * (1 - fu) + image[v0 + 1, u0 + 1] * fu
    return np.asarray(top * (1 - fv) + bottom * fv, np.float64)


@dataclass(frozen=True)
class PhotometricTerm:
    """The intensity residuals of a keyframe's selected pixels moved into a frame."""

    keyframe: KeyframeIntensity
    keyframe_pose: NDArray[np.float64]
    """``T_world_camera`` of the keyframe."""
    frame: FrameIntensity
    """The frame's intensity on the same pyramid level as the keyframe's selection."""
    intensity_std: float
    """σ of one residual in grey levels: the render's or sensor's noise, and more for what the model leaves out
    (shading that changes with the view, interpolation, correlated neighbours)."""
    huber: float = 2.0
    """Huber threshold in standard deviations: an occluded or specular pixel pulls no harder than this."""

    def linearize(self, T_camera_world: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Whitened residuals (m,) and their Jacobian (m, 6) in the left perturbation (translation, rotation) of
        ``T_camera_world``, over the pixels that land inside the frame."""
        # T_camera_key = T_camera_world · T_world_key.
        rotation = T_camera_world[:3, :3] @ self.keyframe_pose[:3, :3]
        translation = T_camera_world[:3, :3] @ self.keyframe_pose[:3, 3] + T_camera_world[:3, 3]
        p = self.keyframe.points @ rotation.T + translation
        k = self.frame.intrinsics
        fx, fy, cx, cy = k.fx, k.fy, k.cx, k.cy
        z = p[:, 2]
        front = z > 1e-3
        inverse_z = 1.0 / np.where(front, z, 1.0)
        u = fx * p[:, 0] * inverse_z + cx
        v = fy * p[:, 1] * inverse_z + cy
        h, w = self.frame.image.shape
        inside = np.flatnonzero(front & (u >= 1.0) & (u < w - 2.0) & (v >= 1.0) & (v < h - 2.0))
        u, v, p, inverse_z = u[inside], v[inside], p[inside], inverse_z[inside]
        residual = (_bilinear(self.frame.image, u, v) - self.keyframe.intensities[inside]) / self.intensity_std
        gu = _bilinear(self.frame.gradient_u, u, v) / self.intensity_std
        gv = _bilinear(self.frame.gradient_v, u, v) / self.intensity_std
        # ∂r/∂p = (gu·fx/z, gv·fy/z, −(gu·fx·x + gv·fy·y)/z²); ∂p/∂δ = [I | −[p]×], so the rotation part is p × a.
        a = np.empty((len(inside), 3))
        a[:, 0] = gu * fx * inverse_z
        a[:, 1] = gv * fy * inverse_z
        a[:, 2] = -(a[:, 0] * p[:, 0] + a[:, 1] * p[:, 1]) * inverse_z
        jacobian = np.empty((len(inside), 6))
        jacobian[:, :3] = a
        jacobian[:, 3:] = np.cross(p, a)
        return residual, jacobian
