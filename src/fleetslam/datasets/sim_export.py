"""The simulator's TUM-like exports (``fleetslam sim export-tum``).

Same layout as a TUM folder (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``) plus the camera model in
``intrinsics.yaml`` (``fx fy cx cy width height`` and optionally ``depth_scale``) or ``camera.txt``
(``fx fy cx cy [width height]``), optionally wheel odometry in ``odometry.txt`` (TUM format, camera
poses in the odometry frame) which becomes each frame's ``prior``, and optionally the camera's mounting on the
robot in ``base_camera.txt`` (4×4 T_base_link_optical) for planar-motion constraints.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.datasets.tum import TUM_DEPTH_SCALE, TumSource, read_intrinsics_file
from fleetslam.errors import DatasetError
from fleetslam.trajectory import NearestPose, read_tum


class SimExportSource(TumSource):
    """A simulator export: a TUM folder with its own intrinsics, ground truth and wheel odometry."""

    def __init__(self, root: Path, max_difference: float = 0.02) -> None:
        intrinsics, depth_scale = self._read_camera(root)
        super().__init__(root, intrinsics, depth_scale, max_difference)
        self.max_difference = max_difference
        odometry_path = root / "odometry.txt"
        self.odometry = read_tum(odometry_path) if odometry_path.is_file() else None
        extrinsics_path = root / "base_camera.txt"
        if extrinsics_path.is_file():
            try:
                extrinsics = np.loadtxt(extrinsics_path, dtype=np.float64)
            except ValueError as err:
                raise DatasetError(f"{extrinsics_path}: not a 4×4 matrix of numbers: {err}") from err
            if extrinsics.shape != (4, 4) or not np.isfinite(extrinsics).all():
                raise DatasetError(f"{extrinsics_path}: expected a finite 4×4 matrix, got shape {extrinsics.shape}")
            self.base_camera = extrinsics

    @staticmethod
    def _read_camera(root: Path) -> tuple[Intrinsics, float]:
        yaml_path = root / "intrinsics.yaml"
        depth_scale = TUM_DEPTH_SCALE
        if yaml_path.is_file():
            data = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
            if isinstance(data, dict) and "depth_scale" in data:
                try:
                    depth_scale = float(data["depth_scale"])
                except (TypeError, ValueError) as err:
                    raise DatasetError(f"{yaml_path}: depth_scale {data['depth_scale']!r} is not a number") from err
            return read_intrinsics_file(yaml_path), depth_scale
        camera_path = root / "camera.txt"
        if camera_path.is_file():
            # The simulator writes "fx fy cx cy width height depth_scale" on one line.
            for line in camera_path.read_text(encoding="utf-8").splitlines():
                fields = line.split("#", 1)[0].split()
                if len(fields) == 7:
                    try:
                        depth_scale = float(fields[6])
                    except ValueError as err:
                        raise DatasetError(f"{camera_path}: depth_scale {fields[6]!r} is not a number") from err
                    break
            return read_intrinsics_file(camera_path), depth_scale
        raise DatasetError(f"{root}: simulator export has neither intrinsics.yaml nor camera.txt")

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        gt = self.groundtruth()
        prior_at = None if self.odometry is None else NearestPose(self.odometry, self.max_difference)
        truth_at = None if gt is None else NearestPose(gt, self.max_difference)
        for frame in super().frames(every):
            if prior_at is not None:
                frame.prior = prior_at(frame.stamp)
            if truth_at is not None:
                frame.groundtruth = truth_at(frame.stamp)
            yield frame


def open_sim_export(path: Path, *, max_difference: float = 0.02) -> SimExportSource:
    """Open a simulator export folder."""
    return SimExportSource(path, max_difference)
