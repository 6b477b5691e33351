from pathlib import Path

import numpy as np
import pytest

from fleetslam.errors import DatasetError
from fleetslam.geometry import random_pose
from fleetslam.trajectory import Trajectory, read_tum, write_tum


def test_tum_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    stamps = 1305031102.175304 + np.arange(10) * 0.033
    traj = Trajectory.from_lists(stamps, [random_pose(rng) for _ in stamps])
    path = tmp_path / "sub" / "traj.txt"
    write_tum(path, traj)
    back = read_tum(path)
    assert len(back) == 10
    # TUM files hold 6 decimals: stamps within 5e-7 (+ 1.2e-7 float64 spacing at 1.3e9 s); quaternion components
    # within 5e-7 each move rotation entries by a few 1e-6 (measured 1.2e-6).
    np.testing.assert_allclose(back.stamps, stamps, atol=1e-6)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-5)


def test_tum_reader_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.txt"
    path.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad.txt:3: expected 8 values"):
        read_tum(path)
    path.write_text("1.0 0 0 x 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad.txt:1: not a number"):
        read_tum(path)
    with pytest.raises(DatasetError, match="not found"):
        read_tum(tmp_path / "missing.txt")


def test_trajectory_shape_checked() -> None:
    with pytest.raises(ValueError, match="stamps"):
        Trajectory(np.zeros(3), np.zeros((2, 4, 4)))
