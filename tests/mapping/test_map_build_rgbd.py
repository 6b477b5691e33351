"""`fleetslam map build` from RGB-D sequences: a simulator export with its ground truth or a trajectory file."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from fleetslam.cli.main import main
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.trajectory import Trajectory, read_tum, write_tum

os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from fleetslam.sim.export import export_tum

    out = tmp_path_factory.mktemp("rgbd") / "line"
    export_tum(out, route="line", frames=10, width=160, height=120, camera_hz=5.0, progress=False)
    return out


def test_build_from_an_export_with_its_ground_truth(
    export: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "map.bt"
    assert main(["map", "build", str(export), "-o", str(out), "--pixel-step", "2", "--no-progress"]) == 0
    assert "10 of 10 frames" in capsys.readouterr().out
    tree = OccupancyOctree.read(out)
    occupied, _ = tree.occupied_centers()
    assert len(occupied) > 100
    # The camera sees the floor in front of the robot: occupied voxels at floor height, free space above them.
    truth = read_tum(export / "groundtruth.txt")
    camera = truth.poses[0][:3, 3]
    floor = occupied[np.abs(occupied[:, 2]) < 0.06]
    assert len(floor) > 50
    ahead = floor[np.argsort(np.linalg.norm(floor[:, :2] - camera[:2], axis=1))[len(floor) // 2]]
    between = camera + 0.5 * (ahead - camera)
    assert tree.is_occupied(between) is False and tree.log_odds(between) is not None


def test_build_with_a_trajectory_file_and_every_other_frame(
    export: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = read_tum(export / "groundtruth.txt")
    trajectory = tmp_path / "trajectory.txt"
    write_tum(trajectory, Trajectory.from_lists(list(truth.stamps[::2]), list(truth.poses[::2])))
    out = tmp_path / "map.ot"
    args = ["map", "build", str(export), "--trajectory", str(trajectory), "-o", str(out), "--no-progress"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "5 of 10 frames" in printed and "5 frames without a pose skipped" in printed
    assert OccupancyOctree.read(out).num_nodes() > 100


def test_errors_name_the_problem(export: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shifted = tmp_path / "shifted.txt"
    truth = read_tum(export / "groundtruth.txt")
    write_tum(shifted, Trajectory.from_lists(list(truth.stamps + 100.0), list(truth.poses)))
    args = ["map", "build", str(export), "--trajectory", str(shifted), "-o", str(tmp_path / "a.bt"), "--no-progress"]
    assert main(args) != 0
    assert "none of its 10 frames has a pose within 0.02 s" in capsys.readouterr().err
    assert not (tmp_path / "a.bt").exists()
    no_truth = tmp_path / "no_truth"
    shutil.copytree(export, no_truth)
    (no_truth / "groundtruth.txt").unlink()
    assert main(["map", "build", str(no_truth), "-o", str(tmp_path / "b.bt"), "--no-progress"]) != 0
    assert "no ground truth; give the camera poses with --trajectory" in capsys.readouterr().err


def test_build_from_a_recording_with_a_trajectory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ..datasets.test_mcap_source import _write

    recording = tmp_path / "run.mcap"
    _write(recording, 6)  # a 6×4 camera 1 m from a wall, stamps 10 + i/30 s
    trajectory = tmp_path / "poses.txt"
    write_tum(trajectory, Trajectory.from_lists([10.0 + i / 30.0 for i in range(6)], [np.eye(4)] * 6))
    out = tmp_path / "wall.bt"
    args = ["map", "build", str(recording), "--trajectory", str(trajectory), "--pixel-step", "1", "-o", str(out)]
    assert main([*args, "--resolution", "0.05", "--no-progress"]) == 0
    assert "6 of 6 frames" in capsys.readouterr().out
    tree = OccupancyOctree.read(out)
    assert tree.is_occupied([0.0, 0.0, 1.0]) is True
    assert tree.is_occupied([0.0, 0.0, 0.5]) is False
    # Without poses a recording cannot be mapped: the error says what to give.
    assert main(["map", "build", str(recording), "-o", str(tmp_path / "x.bt"), "--no-progress"]) != 0
    assert "--trajectory" in capsys.readouterr().err
