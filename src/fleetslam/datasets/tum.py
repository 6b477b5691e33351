"""TUM RGB-D benchmark folders: ``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt``.

RGB and depth images are associated like the TUM ``associate.py`` tool: each RGB stamp takes the closest
unused depth stamp within ``max_difference`` (0.02 s), greedily by smallest difference. Depth PNGs are
16-bit with ``depth_scale`` = 5000 units per metre. Intrinsics come from a file or flags, else from the
folder name (``freiburg1/2/3``), else the ROS default (525, 525, 319.5, 239.5).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.errors import DatasetError
from fleetslam.trajectory import Trajectory, read_tum

logger = logging.getLogger(__name__)

ROS_DEFAULT = Intrinsics(525.0, 525.0, 319.5, 239.5)
#: calibrated intrinsics published with the TUM RGB-D benchmark, per sensor.
TUM_INTRINSICS: dict[str, Intrinsics] = {
    "freiburg1": Intrinsics(517.3, 516.5, 318.6, 255.3),
    "freiburg2": Intrinsics(520.9, 521.0, 325.1, 249.7),
    "freiburg3": Intrinsics(535.4, 539.2, 320.1, 247.6),
}
TUM_DEPTH_SCALE = 5000.0


def read_file_list(path: Path) -> list[tuple[float, str]]:
    """``stamp filename`` lines of a TUM list file (comments and blank lines skipped).

    Raises:
        DatasetError: naming the file and line when a line is malformed.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: list file not found")
    entries: list[tuple[float, str]] = []
    with path.open(encoding="utf-8") as f:
        for lineno, line in enumerate(f, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.replace(",", " ").split()
            if len(fields) < 2:
                raise DatasetError(f"{path}:{lineno}: expected 'timestamp filename', got {text!r}")
            try:
                stamp = float(fields[0])
            except ValueError as err:
                raise DatasetError(f"{path}:{lineno}: timestamp {fields[0]!r} is not a number") from err
            entries.append((stamp, fields[1]))
    return entries


def associate(first: list[float], second: list[float], max_difference: float = 0.02) -> list[tuple[int, int]]:
    """Pairs of indices ``(i, j)`` matching stamps within ``max_difference``, like TUM ``associate.py``.

    Candidate pairs are taken by increasing time difference, each stamp used at most once; the result is
    sorted by the first stamp.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    if a.size == 0 or b.size == 0:
        return []
    order_b = np.argsort(b)
    sorted_b = b[order_b]
    candidates: list[tuple[float, int, int]] = []
    # Only stamps inside the window can pair, so a sorted search keeps this O(n log n) instead of O(n·m).
    lo = np.searchsorted(sorted_b, a - max_difference, side="left")
    hi = np.searchsorted(sorted_b, a + max_difference, side="right")
    for i, (start, stop) in enumerate(zip(lo, hi, strict=True)):
        for k in range(int(start), int(stop)):
            j = int(order_b[k])
            candidates.append((abs(a[i] - b[j]), i, j))
    candidates.sort()
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs: list[tuple[int, int]] = []
    for _, i, j in candidates:
        if i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        pairs.append((i, j))
    pairs.sort()
    return pairs


def intrinsics_for_folder(path: Path) -> Intrinsics:
    """Calibrated intrinsics from a ``freiburgN`` folder name, else the ROS default."""
    name = path.resolve().name.lower()
    for key, value in TUM_INTRINSICS.items():
        if key in name:
            return value
    logger.warning("%s: unknown TUM sensor, using the ROS default intrinsics 525/525/319.5/239.5", path)
    return ROS_DEFAULT


def read_intrinsics_file(path: Path, width: int = 640, height: int = 480) -> Intrinsics:
    """Intrinsics from a text file: ``fx fy cx cy [width height]`` on the first non-comment line, or a
    YAML mapping with those keys.

    Raises:
        DatasetError: naming the file when it holds neither.
    """
    import yaml

    if not path.is_file():
        raise DatasetError(f"{path}: intrinsics file not found")
    text = path.read_text(encoding="utf-8")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        data = None
    if isinstance(data, dict):
        try:
            return Intrinsics(
                float(data["fx"]),
                float(data["fy"]),
                float(data["cx"]),
                float(data["cy"]),
                int(data.get("width", width)),
                int(data.get("height", height)),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise DatasetError(f"{path}: intrinsics mapping needs numeric fx, fy, cx, cy ({err})") from err
    for lineno, line in enumerate(text.splitlines(), start=1):
        fields = line.split("#", 1)[0].replace(",", " ").split()
        if not fields:
            continue
        try:
            values = [float(v) for v in fields]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: expected 'fx fy cx cy [width height]', got {line!r}") from err
        if len(values) not in (4, 6, 7):
            raise DatasetError(
                f"{path}:{lineno}: expected 4, 6 or 7 numbers (fx fy cx cy [width height [depth_scale]])"
            )
        w, h = (int(values[4]), int(values[5])) if len(values) >= 6 else (width, height)
        return Intrinsics(values[0], values[1], values[2], values[3], w, h)
    raise DatasetError(f"{path}: no intrinsics found")


def _cv2() -> Any:
    return require("cv2", "slam")


def load_rgb(path: Path) -> NDArray[np.uint8]:
    """An 8-bit colour image in RGB order."""
    cv2 = _cv2()
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DatasetError(f"{path}: cannot read colour image")
    return np.ascontiguousarray(image[:, :, ::-1])


def load_depth(path: Path, depth_scale: float) -> NDArray[np.float32]:
    """A 16-bit depth PNG as metres (float32, 0 = invalid)."""
    cv2 = _cv2()
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DatasetError(f"{path}: cannot read depth image")
    if raw.ndim != 2:
        raise DatasetError(f"{path}: depth image must have one channel, got shape {raw.shape}")
    if raw.dtype != np.uint16:
        # A float image (32-bit TIFF in metres) divided by the TUM scale is a flat world 5000 times too near: SLAM
        # would return an identity trajectory without a word. Say so instead of guessing the unit.
        raise DatasetError(
            f"{path}: depth image is {raw.dtype}, TUM depth is 16-bit integers of 1/{depth_scale:g} m; "
            "convert it (metres × scale, as uint16 PNG)"
        )
    return (raw.astype(np.float32) / np.float32(depth_scale)).astype(np.float32)


def check_depth_scale(depth_m: NDArray[np.float32], path: Path, depth_scale: float) -> None:
    """Warn loudly when a frame's depths cannot be a camera's at this scale (none valid, or a median nearer than
    0.5 m or farther than 20 m: typically millimetre data read with TUM's 5000 per metre, which puts a room 0.1-1 m
    away)."""
    valid = depth_m[depth_m > 0]
    if valid.size == 0:
        logger.warning("%s: no valid depth in the first frame; is this a depth image?", path)
        return
    median = float(np.median(valid))
    if not 0.5 <= median <= 20.0:
        logger.warning(
            "%s: median depth %.3f m at depth_scale %g is not a camera's; millimetre data needs depth_scale 1000 "
            "(the 7th number of the intrinsics file)", path, median, depth_scale,
        )  # fmt: skip


class TumSource:
    """A TUM RGB-D folder; images are read while iterating."""

    base_camera: NDArray[np.float64] | None = None
    """T_base_camera when the camera's mounting on a ground robot is known (simulator exports), else None."""

    def __init__(
        self,
        root: Path,
        intrinsics: Intrinsics | None = None,
        depth_scale: float = TUM_DEPTH_SCALE,
        max_difference: float = 0.02,
        rgb_list: str = "rgb.txt",
        depth_list: str = "depth.txt",
    ) -> None:
        if not root.is_dir():
            raise DatasetError(f"{root}: TUM dataset folder not found")
        self.root = root
        self.name = root.resolve().name
        self.depth_scale = depth_scale
        self.intrinsics = intrinsics or intrinsics_for_folder(root)
        rgb = read_file_list(root / rgb_list)
        depth = read_file_list(root / depth_list)
        pairs = associate([s for s, _ in rgb], [s for s, _ in depth], max_difference)
        if not pairs:
            raise DatasetError(f"{root}: no RGB/depth pairs within {max_difference} s")
        self._pairs = [(rgb[i][0], root / rgb[i][1], root / depth[j][1]) for i, j in pairs]
        gt_path = root / "groundtruth.txt"
        self._groundtruth = read_tum(gt_path) if gt_path.is_file() else None

    def __len__(self) -> int:
        return len(self._pairs)

    def __iter__(self) -> Iterator[RGBDFrame]:
        return self.frames()

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        for index in range(0, len(self._pairs), every):
            stamp, rgb_path, depth_path = self._pairs[index]
            depth = load_depth(depth_path, self.depth_scale)
            if index == 0:
                check_depth_scale(depth, depth_path, self.depth_scale)
            yield RGBDFrame(index, stamp, load_rgb(rgb_path), depth)

    def groundtruth(self) -> Trajectory | None:
        return self._groundtruth


def open_tum(
    path: Path,
    *,
    intrinsics: Intrinsics | None = None,
    intrinsics_file: str | Path | None = None,
    depth_scale: float = TUM_DEPTH_SCALE,
    max_difference: float = 0.02,
) -> TumSource:
    """Open a TUM folder (``intrinsics`` or ``intrinsics_file`` override the folder-name default)."""
    if intrinsics is None and intrinsics_file is not None:
        intrinsics = read_intrinsics_file(Path(intrinsics_file))
    return TumSource(path, intrinsics, depth_scale, max_difference)
