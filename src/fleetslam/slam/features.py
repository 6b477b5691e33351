"""Keypoints and descriptors with OpenCV, bucketed on a grid so that they cover the image evenly."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require


def import_cv2() -> Any:
    """OpenCV, or a MissingExtraError naming the ``slam`` extra."""
    return require("cv2", "slam")


@dataclass
class Features:
    """``keypoints (N, 2) float32`` pixel coordinates, ``descriptors (N, D)``, detector ``responses (N,)`` and
    ``scales (N,)``: the pixel size of the pyramid level each keypoint was found on, in full-resolution pixels
    (1 on the finest level), which is also the standard deviation of its position in units of the finest pixel."""

    keypoints: NDArray[np.float32]
    descriptors: NDArray[Any]
    responses: NDArray[np.float32]
    scales: NDArray[np.float32] = field(default_factory=lambda: np.zeros(0, np.float32))

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])


def bucket(
    points: NDArray[np.float32],
    responses: NDArray[np.float32],
    shape: tuple[int, int],
    rows: int,
    cols: int,
    max_total: int,
) -> NDArray[np.intp]:
    """Indices of at most ``max_total`` points: the strongest ``max_total / (rows·cols)`` of every grid cell
    first (even coverage), then the budget that weak cells left unused goes to the strongest of the rest."""
    if len(points) <= max_total:
        return np.arange(len(points), dtype=np.intp)
    h, w = shape
    r = np.clip((points[:, 1] * rows / h).astype(np.intp), 0, rows - 1)
    c = np.clip((points[:, 0] * cols / w).astype(np.intp), 0, cols - 1)
    cell = r * cols + c
    per_cell = max(1, max_total // (rows * cols))
    order = np.lexsort((-responses, cell))
    sorted_cells = cell[order]
    starts = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.arange(len(order)) - starts
    chosen = order[rank < per_cell]
    rest = order[rank >= per_cell]
    spare = max_total - len(chosen)
    if spare > 0 and len(rest):
        chosen = np.concatenate([chosen, rest[np.argsort(-responses[rest])[:spare]]])
    return np.sort(chosen)


class FeatureExtractor:
    """ORB (default), SIFT or AKAZE on a grayscale image, bucketed on a grid."""

    def __init__(
        self,
        kind: str = "orb",
        max_features: int = 1000,
        grid_rows: int = 4,
        grid_cols: int = 4,
        orb_fast_threshold: int = 12,
        orb_levels: int = 4,
        orb_patch_size: int = 31,
        *,
        subpixel_window: int = 0,
    ) -> None:
        """``subpixel_window`` > 0: ORB keypoints are refined to sub-pixel positions (:class:`SubpixelRefiner`,
        with that window, allowed to move within it)."""
        cv2 = import_cv2()
        self.kind = kind
        self.max_features = max_features
        self.scale_factor = 1.2  # OpenCV's ORB default pyramid step
        self.grid = (grid_rows, grid_cols)
        self._refiner = SubpixelRefiner(subpixel_window) if subpixel_window > 0 else None
        # Detect more than kept so that bucketing can choose per cell.
        n_detect = 2 * max_features
        if kind == "orb":
            self._detector = cv2.ORB_create(
                nfeatures=n_detect,
                nlevels=orb_levels,
                fastThreshold=orb_fast_threshold,
                scoreType=cv2.ORB_FAST_SCORE,
                patchSize=orb_patch_size,
                edgeThreshold=orb_patch_size,
            )
        elif kind == "sift":
            self._detector = cv2.SIFT_create(nfeatures=n_detect)
        elif kind == "akaze":
            if not hasattr(cv2, "AKAZE_create"):  # OpenCV 5 moved AKAZE out of its main modules
                raise ValueError(f"feature kind 'akaze' needs an OpenCV with AKAZE; OpenCV {cv2.__version__} has none")
            self._detector = cv2.AKAZE_create()
        else:
            raise ValueError(f"feature kind {kind!r} is not one of orb, sift, akaze")

    @property
    def binary(self) -> bool:
        """Whether descriptors are binary (Hamming distance)."""
        return self.kind in ("orb", "akaze")

    def detect(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Features:
        """Keypoints and descriptors of one grayscale image."""
        if self.kind == "orb":
            # One pass: ORB's compute() builds the image pyramid again, which costs more than describing the
            # keypoints bucketing will drop (the kept descriptors are the same bytes either way).
            keypoints, descriptors = self._detector.detectAndCompute(gray, mask)
            if keypoints and descriptors is not None:
                pts, resp = _points(keypoints)
                keep = bucket(pts, resp, gray.shape[:2], self.grid[0], self.grid[1], self.max_features)
                keypoints, descriptors = [keypoints[i] for i in keep], descriptors[keep]
                pts, resp = pts[keep], resp[keep]
        else:  # SIFT/AKAZE: describing is the expensive part, so only the keypoints kept are described
            keypoints = self._detector.detect(gray, mask)
            if keypoints:
                pts, resp = _points(keypoints)
                keep = bucket(pts, resp, gray.shape[:2], self.grid[0], self.grid[1], self.max_features)
                keypoints = [keypoints[i] for i in keep]
            keypoints, descriptors = self._detector.compute(gray, keypoints)
            if keypoints:  # compute() may drop keypoints it cannot describe
                pts, resp = _points(keypoints)
        if descriptors is None or not keypoints:
            dim, dtype = (32, np.uint8) if self.binary else (128, np.float32)
            empty = np.zeros(0, np.float32)
            return Features(np.zeros((0, 2), np.float32), np.zeros((0, dim), dtype), empty, empty)
        if self.kind == "orb":
            scales = (self.scale_factor ** np.array([k.octave & 0xFF for k in keypoints])).astype(np.float32)
            # ORB reports a level's pixel x_L as x_L·s; its centre is at (x_L + ½)·s − ½ in the full image.
            pts += ((scales - 1.0) / 2.0)[:, None]
            if self._refiner is not None:
                pts = self._refiner.refine(gray, pts, scales)
        else:  # SIFT/AKAZE: the keypoint's size relative to the smallest detected stands in for the level
            sizes = np.array([k.size for k in keypoints], dtype=np.float32)
            scales = np.maximum(sizes / max(float(sizes.min()), 1e-6), 1.0).astype(np.float32)
        return Features(pts, descriptors, resp, scales)


class SubpixelRefiner:
    """Moves keypoints to the sub-pixel corner position in the image: the point ``q`` to which the image gradients
    ``g`` around it are orthogonal, ``Σ g gᵀ (q − p) = 0`` over the pixels ``p`` of a square window of
    ``window·scale`` pixels either side, ``scale`` the pixel size of the keypoint's pyramid level (Förstner's
    corner, as OpenCV's ``cornerSubPix`` finds it, there with resampled windows). The window sums come from
    integral images, a few look-ups per point whatever its window; the window is re-centred on the nearest pixel
    ``iterations`` times. A point whose window holds no corner (a nearly singular ``Σ g gᵀ``: an edge or a flat
    patch), that moves farther than ``max_shift·scale`` pixels or leaves the image keeps its position. The image
    buffers are kept from one call to the next: fresh ones cost more in page faults than the arithmetic."""

    def __init__(self, window: int, max_shift: float | None = None, iterations: int = 3) -> None:
        """``max_shift`` defaults to ``window``: a point that leaves its window has not found its own corner."""
        self.window = window
        self.max_shift = float(window) if max_shift is None else max_shift
        self.iterations = iterations
        self._buffers: dict[str, NDArray[Any]] = {}
        self._shape: tuple[int, int] | None = None

    def _integrals(self, gray: NDArray[np.uint8]) -> list[NDArray[np.float64]]:
        """Integral images (raveled, float64: window sums are differences of sums over the whole image) of
        ``gx², gx·gy, gy²`` and of the two components of ``g gᵀ p``."""
        cv2 = import_cv2()
        h, w = gray.shape[:2]
        if self._shape != (h, w):
            self._shape = (h, w)
            self._buffers = {k: np.empty((h, w), np.float32) for k in ("gx", "gy", "xx", "xy", "yy", "bx", "by", "t")}
            self._buffers |= {f"i{k}": np.empty((h + 1, w + 1), np.float64) for k in range(5)}
            self._buffers["xs"] = np.arange(w, dtype=np.float32)[None, :]
            self._buffers["ys"] = np.arange(h, dtype=np.float32)[:, None]
        b = self._buffers
        gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, dst=b["gx"], ksize=1)
        gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, dst=b["gy"], ksize=1)
        gxx, gxy, gyy = (
            np.multiply(gx, gx, out=b["xx"]),
            np.multiply(gx, gy, out=b["xy"]),
            np.multiply(gy, gy, out=b["yy"]),
        )
        bx = np.multiply(gxx, b["xs"], out=b["bx"])
        bx += np.multiply(gxy, b["ys"], out=b["t"])
        by = np.multiply(gxy, b["xs"], out=b["by"])
        by += np.multiply(gyy, b["ys"], out=b["t"])
        return [
            cv2.integral(m, sum=b[f"i{k}"], sdepth=cv2.CV_64F).ravel() for k, m in enumerate((gxx, gxy, gyy, bx, by))
        ]

    def refine(
        self, gray: NDArray[np.uint8], points: NDArray[np.float32], scales: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        """``points (N, 2)`` of ``gray``, found on levels of pixel size ``scales (N,)``, refined."""
        h, w = gray.shape[:2]
        integrals = self._integrals(gray)
        half = np.maximum(1, np.rint(self.window * scales.astype(np.float64))).astype(np.intp)
        q = points.astype(np.float64)
        valid = np.ones(len(q), bool)
        for _ in range(self.iterations):
            cx = np.clip(np.rint(q[:, 0]).astype(np.intp), 0, w - 1)
            cy = np.clip(np.rint(q[:, 1]).astype(np.intp), 0, h - 1)
            x0, x1 = np.clip(cx - half, 0, w), np.clip(cx + half + 1, 0, w)
            y0, y1 = np.clip(cy - half, 0, h) * (w + 1), np.clip(cy + half + 1, 0, h) * (w + 1)
            i11, i01, i10, i00 = y1 + x1, y0 + x1, y1 + x0, y0 + x0
            sxx, sxy, syy, bx, by = (s[i11] - s[i01] - s[i10] + s[i00] for s in integrals)
            det = sxx * syy - sxy * sxy
            trace = sxx + syy
            valid &= det > 1e-4 * trace * trace  # the smaller eigenvalue is not negligible: gradients both ways
            safe = np.where(valid, det, 1.0)
            solved = np.stack([(syy * bx - sxy * by) / safe, (sxx * by - sxy * bx) / safe], 1)
            q = np.where(valid[:, None], solved, q)
        shift = np.linalg.norm(q - points, axis=1)
        inside = (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
        good = valid & inside & (shift <= self.max_shift * scales)
        return np.where(good[:, None], q, points).astype(np.float32)


def _points(keypoints: Sequence[Any]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """OpenCV keypoints' positions (N, 2) and responses (N,)."""
    pts = import_cv2().KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2)
    return pts, np.array([k.response for k in keypoints], dtype=np.float32)
