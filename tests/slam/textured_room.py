"""A textured box room rendered by ray casting with a pinhole camera: RGB-D frames with exact depth."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics

HALF_SIZE = 2.5
TEXELS = 512


def make_textures(rng: np.random.Generator) -> list[NDArray[np.uint8]]:
    """One texture per face: random shapes of random grey levels give ORB plenty of corners."""
    textures = []
    for _ in range(6):
        tex = np.full((TEXELS, TEXELS), 128, np.uint8)
        for _ in range(350):
            x, y = (int(v) for v in rng.integers(0, TEXELS, 2))
            size = int(rng.integers(4, 30))
            shade = int(rng.integers(0, 256))
            if rng.random() < 0.5:
                cv2.rectangle(tex, (x, y), (x + size, y + int(rng.integers(4, 30))), shade, -1)
            else:
                cv2.circle(tex, (x, y), size // 2, shade, -1)
        textures.append(tex)
    return textures


def render(
    pose: NDArray[np.float64], intrinsics: Intrinsics, textures: list[NDArray[np.uint8]]
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """RGB (grey in 3 channels) and depth (metres, camera z) of the room seen from ``T_world_camera``.

    The image is rendered at twice the resolution and averaged down, and textures are sampled bilinearly (a
    lens blurs): with nearest-texel sampling, corners jump by whole texels between views and keypoints carry
    up to a pixel of view-dependent noise that no real camera has."""
    k = intrinsics
    fine = Intrinsics(2 * k.fx, 2 * k.fy, 2 * k.cx + 0.5, 2 * k.cy + 0.5, 2 * k.width, 2 * k.height)
    gray_fine, _ = _raycast(pose, fine, textures)
    _, depth = _raycast(pose, k, textures)
    gray = cv2.resize(gray_fine, (k.width, k.height), interpolation=cv2.INTER_AREA)
    return np.repeat(gray[:, :, None], 3, axis=2), depth


def image_messages(
    pose: NDArray[np.float64], stamp_ns: int, intrinsics: Intrinsics, textures: list[NDArray[np.uint8]]
) -> tuple[Any, Any]:
    """:func:`render`'s view as the camera topics carry it: ``sensor_msgs/Image`` rgb8 and 32FC1 (metres)."""
    from fleetslam.msg.typesys import get_type, header

    rgb, depth = render(pose, intrinsics, textures)
    image = get_type("sensor_msgs/msg/Image")
    width, height = intrinsics.width, intrinsics.height
    return (
        image(header=header("camera", stamp_ns), height=height, width=width, encoding="rgb8", is_bigendian=0,
              step=3 * width, data=np.ascontiguousarray(rgb).reshape(-1)),
        image(header=header("camera", stamp_ns), height=height, width=width, encoding="32FC1", is_bigendian=0,
              step=4 * width, data=np.ascontiguousarray(depth, np.float32).view(np.uint8).reshape(-1)),
    )  # fmt: skip


def _raycast(
    pose: NDArray[np.float64], intrinsics: Intrinsics, textures: list[NDArray[np.uint8]]
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    w, h = intrinsics.width, intrinsics.height
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays_cam = np.stack(
        [(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones_like(u)], axis=-1
    ).reshape(-1, 3)
    dirs = rays_cam @ pose[:3, :3].T
    origin = pose[:3, 3]
    best_t = np.full(dirs.shape[0], np.inf)
    best_face = np.zeros(dirs.shape[0], np.intp)
    for axis in range(3):
        d = dirs[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            for sign_index, wall in enumerate((-HALF_SIZE, HALF_SIZE)):
                t = (wall - origin[axis]) / d
                ok = (t > 0) & (t < best_t)
                best_t = np.where(ok, t, best_t)
                best_face = np.where(ok, 2 * axis + sign_index, best_face)
    hits = origin + dirs * best_t[:, None]
    gray = np.zeros(dirs.shape[0], np.uint8)
    for face in range(6):
        sel = best_face == face
        axis = face // 2
        a, b = [k for k in range(3) if k != axis]
        ta = np.clip((hits[sel, a] + HALF_SIZE) / (2 * HALF_SIZE) * (TEXELS - 1), 0, TEXELS - 1.001)
        tb = np.clip((hits[sel, b] + HALF_SIZE) / (2 * HALF_SIZE) * (TEXELS - 1), 0, TEXELS - 1.001)
        gray[sel] = _bilinear(textures[face], ta, tb)
    depth = (best_t * rays_cam[:, 2]).reshape(h, w).astype(np.float32)
    return gray.reshape(h, w), depth


def _bilinear(texture: NDArray[np.uint8], ta: NDArray[np.float64], tb: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Texture values at continuous texel coordinates (column ``ta``, row ``tb``), bilinearly interpolated."""
    ia, ib = ta.astype(np.intp), tb.astype(np.intp)
    fa, fb = ta - ia, tb - ib
    tex = texture.astype(np.float64)
    top = tex[ib, ia] * (1 - fa) + tex[ib, ia + 1] * fa
    bottom = tex[ib + 1, ia] * (1 - fa) + tex[ib + 1, ia + 1] * fa
    return np.clip(np.rint(top * (1 - fb) + bottom * fb), 0, 255).astype(np.uint8)
