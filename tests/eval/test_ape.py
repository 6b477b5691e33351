from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fleetslam.errors import DatasetError
from fleetslam.eval import ape, fleet_ape, rpe
from fleetslam.geometry import invert, make_pose, so3_exp
from fleetslam.trajectory import Trajectory


def _line(n: int, offset: np.ndarray | None = None, stamp_shift: float = 0.0) -> Trajectory:
    poses = []
    for i in range(n):
        p = make_pose(translation=[0.1 * i, np.sin(i / 3.0), 0.0])
        if offset is not None:
            p[:3, 3] += offset[i]
        poses.append(p)
    return Trajectory.from_lists([i * 0.1 + stamp_shift for i in range(n)], poses)


def test_ape_without_alignment_equals_hand_computed_offset() -> None:
    offsets = np.zeros((20, 3))
    offsets[::2, 2] = 0.03
    offsets[1::2, 2] = 0.01
    result = ape(_line(20), _line(20, offsets), align=False)
    assert result.rmse == pytest.approx(np.sqrt((0.03**2 + 0.01**2) / 2))
    assert result.pairs == 20
    assert "none" in result.conventions


def test_ape_alignment_removes_a_constant_offset() -> None:
    offsets = np.tile([0.5, -0.2, 0.1], (20, 1))
    # Umeyama on exact data leaves float64 round-off (~2e-16 measured); a wrong alignment would leave ~0.5 m
    assert ape(_line(20), _line(20, offsets)).rmse == pytest.approx(0.0, abs=1e-9)


def test_association_tolerance_and_rpe() -> None:
    gt = _line(20)
    est = _line(20, stamp_shift=0.01)
    assert ape(gt, est).pairs == 20
    with pytest.raises(DatasetError):
        ape(gt, _line(20, stamp_shift=0.05))
    offsets = np.zeros((20, 3))
    offsets[10:, 0] = 0.05
    r = rpe(gt, _line(20, offsets), delta=1, delta_unit="f")
    assert r.max == pytest.approx(0.05)


def test_plot_shows_every_estimate_with_its_error(tmp_path: Path) -> None:
    import matplotlib.image

    from fleetslam.eval import plot_ape

    gt = _line(60)
    offsets = np.zeros((60, 3))
    offsets[30:, 1] = 0.05  # a jump half way: alignment cannot remove it
    shifted = _line(60, offsets)
    png = tmp_path / "ape.png"
    plot_ape(gt, gt, str(png), others={"shifted": shifted}, title="two estimates")
    image = matplotlib.image.imread(png)
    assert image.shape[0] > 300 and image.shape[1] > 2 * image.shape[0] * 0.9  # two panels side by side
    # Blue (estimate) and red (the other) curves are both drawn.
    rgb = image[..., :3]
    assert np.any((rgb[..., 2] > 0.8) & (rgb[..., 0] < 0.2)) and np.any((rgb[..., 0] > 0.8) & (rgb[..., 2] < 0.2))


def _moved(trajectory: Trajectory, transform: np.ndarray) -> Trajectory:
    return Trajectory(trajectory.stamps, np.einsum("ij,njk->nik", transform, trajectory.poses))


def test_fleet_ape_aligns_all_robots_once() -> None:
    """Two robots placed correctly in a fleet frame give no error and the fleet frame's pose; the second robot
    misplaced by 0.4 m counts in the fleet APE, although each robot aligned alone would show none."""
    first, second = _line(20), _moved(_line(20, stamp_shift=0.05), make_pose(translation=[0.0, 2.0, 0.0]))
    world_fleet = make_pose(so3_exp([0.1, -0.2, 0.7]), [3.0, -1.0, 0.2])
    fleet_of = invert(world_fleet)
    result, alignment = fleet_ape({"a": (first, _moved(first, fleet_of)), "b": (second, _moved(second, fleet_of))})
    assert result.rmse == pytest.approx(0.0, abs=1e-9)
    assert result.pairs == 40
    np.testing.assert_allclose(alignment, world_fleet, atol=1e-9)
    misplaced = _moved(second, make_pose(translation=[0.4, 0.0, 0.0]) @ fleet_of)
    assert ape(second, misplaced).rmse == pytest.approx(0.0, abs=1e-9)
    wrong, _ = fleet_ape({"a": (first, _moved(first, fleet_of)), "b": (second, misplaced)})
    assert 0.15 < wrong.rmse < 0.4
    with pytest.raises(DatasetError, match="at least one"):
        fleet_ape({})
