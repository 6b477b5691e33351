"""RGB-D frame sources: the frame type, the source protocol and a typed registry of loaders.

A source is opened by name (``tum``, ``sim``, ``mcap``) or by guessing from the path, and yields
:class:`RGBDFrame` lazily: images are read from disk only when the frame is reached in iteration.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import DatasetError
from fleetslam.intrinsics import Intrinsics
from fleetslam.trajectory import Trajectory


@dataclass
class RGBDFrame:
    """One registered RGB-D frame: ``rgb (H, W, 3) uint8`` (RGB order), ``depth (H, W) float32`` metres
    (0 = invalid), the capture stamp in seconds and, when the source has it, a prior pose (wheel odometry,
    ``T_odom_camera``) and the ground-truth camera pose."""

    index: int
    stamp: float
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    prior: NDArray[np.float64] | None = None
    groundtruth: NDArray[np.float64] | None = None


@runtime_checkable
class RGBDSource(Protocol):
    """A sequence of RGB-D frames with known intrinsics."""

    intrinsics: Intrinsics
    """Camera intrinsics of the depth-registered colour image."""
    name: str
    """Short name for logs and results (the folder name)."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[RGBDFrame]: ...

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        """Every ``every``-th frame (the first one included), with its index in the whole sequence; the frames in
        between are not read."""
        ...

    def groundtruth(self) -> Trajectory | None:
        """Ground-truth camera trajectory when the dataset has one."""
        ...


SourceFactory = Callable[..., RGBDSource]

#: loader name -> "module:function" opening a path; imported lazily so that ``tum`` never imports ``mcap``.
LOADERS: Mapping[str, str] = {
    "tum": "fleetslam.datasets.tum:open_tum",
    "sim": "fleetslam.datasets.sim_export:open_sim_export",
    "mcap": "fleetslam.datasets.mcap_source:open_mcap",
}


def guess_kind(path: str | Path) -> str:
    """Guess the loader for a path: ``.mcap`` files / rosbag2 folders, simulator exports, TUM folders."""
    path = Path(path)
    if path.suffix == ".mcap" or (path.is_dir() and any(path.glob("*.mcap"))):
        return "mcap"
    if path.is_dir() and ((path / "camera.txt").is_file() or (path / "intrinsics.yaml").is_file()):
        return "sim"
    if path.is_dir() and (path / "rgb.txt").is_file():
        return "tum"
    raise DatasetError(
        f"{path}: cannot tell the dataset kind (no rgb.txt, camera.txt/intrinsics.yaml or .mcap); "
        f"name it with --kind one of {sorted(LOADERS)}"
    )


def open_source(path: str | Path, kind: str | None = None, **options: object) -> RGBDSource:
    """Open an RGB-D source by loader name (``kind``) or by guessing from ``path``.

    Raises:
        DatasetError: unknown kind, missing or malformed dataset.
    """
    kind = kind or guess_kind(path)
    if kind not in LOADERS:
        raise DatasetError(f"dataset kind {kind!r} is unknown; known kinds: {sorted(LOADERS)}")
    module_name, func_name = LOADERS[kind].split(":")
    factory: SourceFactory = getattr(importlib.import_module(module_name), func_name)
    return factory(Path(path), **options)
