"""What a run's folder holds, read for the reports and the console's replay of a session (``fleetslam report DIR``,
``fleetslam station --session DIR``): JSON figures, where each robot's map lies in the fleet frame, the TUM
trajectories and a map's occupied voxels. Anything missing or unreadable is logged and left out, never invented.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import FleetslamError

log = logging.getLogger(__name__)

__all__ = ["load_json", "occupied_centres", "read_placements", "read_trajectories"]


def load_json(path: Path) -> Any:
    """A JSON file's content; None when it is missing or not JSON (logged)."""
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except ValueError as err:
        log.warning("%s is not JSON (%s): left out", path, err)
        return None


def read_placements(run: Path) -> dict[str, NDArray[np.float64]]:
    """Per robot, ``T_fleet_map``: from ``fleet_frame.json``, and the identity for the robot whose map is the fleet
    frame (``start_poses.yaml``'s ``fleet_frame_of``)."""
    out: dict[str, NDArray[np.float64]] = {}
    placed = load_json(run / "fleet_frame.json") or {}
    for robot, entry in placed.items():
        try:
            out[robot] = np.asarray(entry["T_fleet_map"], dtype=np.float64).reshape(4, 4)
        except (KeyError, TypeError, ValueError):
            log.warning("fleet_frame.json: no T_fleet_map for %s", robot)
    settings = run / "start_poses.yaml"
    if settings.is_file():
        import yaml

        reference = (yaml.safe_load(settings.read_text()) or {}).get("fleet_frame_of")
        if isinstance(reference, str):
            out.setdefault(reference, np.eye(4))
    return out


def read_trajectories(run: Path, folder: str) -> dict[str, Any]:
    """Every ``<robot>.txt`` of ``run/folder`` (TUM) by robot; an unreadable file is logged and left out."""
    from fleetslam.trajectory import read_tum

    directory = run / folder
    out: dict[str, Any] = {}
    for path in sorted(directory.glob("*.txt")) if directory.is_dir() else []:
        try:
            out[path.stem] = read_tum(path)
        except (FleetslamError, ValueError) as err:
            log.warning("%s: %s", path, err)
    return out


def occupied_centres(path: Path) -> NDArray[np.float64]:
    """The centres of an OctoMap file's occupied leaves (n×3)."""
    from fleetslam.mapping.octree import OccupancyOctree

    centres, _ = OccupancyOctree.read(path).occupied_centers()
    return np.asarray(centres, dtype=np.float64)
