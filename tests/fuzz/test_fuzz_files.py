"""Issue 18, item 4: every file reader gets random, truncated and bit-flipped versions of a valid file; each either
reads it or raises a FleetslamError naming the problem, never anything else (a traceback for the user).
Seeded mutations (Hypothesis and atheris are not installed here); FLEETSLAM_FUZZ_FILES sets the count per reader."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam.config import read_yaml
from fleetslam.datasets import open_source
from fleetslam.errors import FleetslamError
from fleetslam.geometry import pose_from_planar
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.mapping.scan_io import ScanNode, load_scan_graph, read_scan_log, read_xyz, write_scan_graph
from fleetslam.trajectory import Trajectory, read_tum, write_tum

from ..datasets.test_mcap_source import _write as write_mcap

PER_READER = int(os.environ.get("FLEETSLAM_FUZZ_FILES", "150"))


def _valid_files(tmp: Path) -> dict[str, tuple[Path, Callable[[Path], Any]]]:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(np.array([[1.0, 0.0, 0.5], [1.0, 0.2, 0.5], [2.0, 1.0, 0.3]]), [0.0, 0.0, 0.5])
    tree.write_binary(tmp / "map.bt")
    tree.write(tmp / "map.ot")
    (tmp / "points.xyz").write_text("".join(f"{k * 0.1} {k * 0.2} 1.0\n" for k in range(50)))
    (tmp / "scans.log").write_text("NODE 0 0 0 0 0 0\n1 0 0\n0 1 0\nNODE 1 0 0 0 0 0.5\n1 1 1\n")
    write_scan_graph(tmp / "scans.graph", [ScanNode(k, pose_from_planar(k, 0.0, 0.1 * k),
                                                    np.ones((5, 3), np.float32)) for k in range(3)])  # fmt: skip
    write_tum(tmp / "poses.txt", Trajectory.from_lists([0.0, 0.1, 0.2], [pose_from_planar(k, 0, 0) for k in range(3)]))
    (tmp / "config.yaml").write_text("slam:\n  max_features: 500\nmap_frame: map\npeers: [r2d2]\n")
    write_mcap(tmp / "frames.mcap", 3)
    return {
        "bt": (tmp / "map.bt", OccupancyOctree.read),
        "ot": (tmp / "map.ot", OccupancyOctree.read),
        "xyz": (tmp / "points.xyz", read_xyz),
        "log": (tmp / "scans.log", read_scan_log),
        "graph": (tmp / "scans.graph", load_scan_graph),
        "tum": (tmp / "poses.txt", read_tum),
        "yaml": (tmp / "config.yaml", read_yaml),
        "mcap": (tmp / "frames.mcap", lambda p: list(open_source(p))),
    }


def _mutations(valid: bytes, rng: np.random.Generator, count: int) -> list[bytes]:
    out = []
    for k in range(count):
        kind = k % 3
        if kind == 0:
            out.append(valid[: int(rng.integers(0, len(valid)))])
        elif kind == 1:
            data = bytearray(valid)
            for _ in range(int(rng.integers(1, 6))):
                index = int(rng.integers(0, len(data)))
                data[index] ^= 1 << int(rng.integers(0, 8))
            out.append(bytes(data))
        else:
            out.append(rng.bytes(int(rng.integers(0, 2 * len(valid) + 1))))
    return out


@pytest.mark.parametrize("reader", ["bt", "ot", "xyz", "log", "graph", "tum", "yaml", "mcap"])
def test_readers_raise_only_fleetslam_errors_on_mutated_files(tmp_path: Path, reader: str) -> None:
    path, read = _valid_files(tmp_path)[reader]
    read(path)  # the valid file reads
    valid = path.read_bytes()
    rng = np.random.default_rng(sum(map(ord, reader)))
    failures: list[str] = []
    refused = 0
    for k, data in enumerate(_mutations(valid, rng, PER_READER)):
        bad = tmp_path / f"bad{k}{path.suffix}"
        bad.write_bytes(data)
        try:
            read(bad)
        except FleetslamError as err:
            refused += 1
            assert str(bad) in str(err) or bad.name in str(err), f"{reader}: error does not name the file: {err}"
        except Exception as err:  # what the user would see as a traceback
            failures.append(f"{type(err).__name__}: {err}"[:200])
        bad.unlink()
    assert not failures, f"{reader}: {len(failures)} of {PER_READER} mutations escaped: {failures[:5]}"
    assert refused > 0
