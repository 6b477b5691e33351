"""One-pass offscreen RGB-D rendering with MuJoCo's public low-level API.

``mujoco.Renderer`` renders the scene twice for colour and depth; here one ``mjr_render`` fills both buffers
and ``mjr_readPixels`` reads them together, halving the cost per RGB-D frame. Depth is read in MuJoCo's
reversed-Z mode and converted to metric z-depth along the optical axis.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


class RGBDRenderer:
    """Renders fixed model cameras at one resolution. Use it from one thread (the GL context is bound to it)."""

    def __init__(self, mujoco: Any, model: Any, width: int, height: int, *, max_geom: int = 10000) -> None:
        self._mujoco = mujoco
        self._model = model
        self.width = width
        self.height = height
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
            mujoco.mjtRndFlag.mjRND_SEGMENT,
        ):
            self.scene.flags[flag] = False
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)
        self._depth = np.empty((height, width), dtype=np.float32)
        extent = model.stat.extent
        znear = np.float32(model.vis.map.znear * extent)
        zfar = np.float32(model.vis.map.zfar * extent)
        # OpenGL projection coefficients (float32 like glFrustum) remapped for reversed Z, as MuJoCo reads depth
        c_coef = -(zfar + znear) / (zfar - znear)
        d_coef = -(np.float32(2) * zfar * znear) / (zfar - znear)
        self._c = float(np.float32(-0.5) * c_coef - np.float32(0.5))
        self._d = float(np.float32(-0.5) * d_coef)

    def render(self, data: Any, camera_id: int) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """(RGB (H, W, 3) uint8, z-depth (H, W) float32 m) seen by model camera ``camera_id``."""
        mujoco = self._mujoco
        self._gl.make_current()
        self._camera.fixedcamid = camera_id
        mujoco.mjv_updateScene(
            self._model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL.value, self.scene
        )
        mujoco.mjr_render(self._rect, self.scene, self._context)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._context)
        rgb = np.flipud(self._rgb).copy()
        depth = (self._d / (np.flipud(self._depth).astype(np.float64) + self._c)).astype(np.float32)
        return rgb, depth

    def close(self) -> None:
        """Free the GL resources (from the thread that rendered)."""
        if self._gl is not None:
            self._gl.make_current()
            self._context.free()
            self._gl.free()
            self._gl = None
