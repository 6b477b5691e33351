import numpy as np
import pytest

from fleetslam.fusion.alignment import rigid_fit
from fleetslam.geometry import random_pose


def test_rigid_fit_recovers_transform() -> None:
    rng = np.random.default_rng(1)
    truth = random_pose(rng, 5.0)
    pts = rng.normal(size=(30, 3))
    moved = pts @ truth[:3, :3].T + truth[:3, 3]
    np.testing.assert_allclose(rigid_fit(pts, moved), truth, atol=1e-9)  # exact data: SVD round-off (~6e-16)
    with pytest.raises(ValueError, match="rigid_fit needs"):
        rigid_fit(pts[:2], moved[:2])


def test_rigid_fit_is_a_rotation_for_mirrored_points() -> None:
    # Points mirrored through a plane: the best proper rotation, never a reflection.
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(20, 3))
    mirrored = pts * np.array([1.0, 1.0, -1.0])
    fitted = rigid_fit(pts, mirrored)
    assert np.linalg.det(fitted[:3, :3]) == pytest.approx(1.0)
