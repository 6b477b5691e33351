import numpy as np
import pytest

from fleetslam.fusion.alignment import InterAgentClosure, estimate_agent_transform, rigid_fit
from fleetslam.geometry import invert, pose_from_planar, random_pose


def _world() -> dict[str, np.ndarray]:
    # True map frames of two agents in the fleet frame.
    return {"c3po": np.eye(4), "r2d2": pose_from_planar(12.0, -3.0, 1.1)}


def test_rigid_fit_recovers_transform() -> None:
    rng = np.random.default_rng(1)
    truth = random_pose(rng, 5.0)
    pts = rng.normal(size=(30, 3))
    moved = pts @ truth[:3, :3].T + truth[:3, 3]
    np.testing.assert_allclose(rigid_fit(pts, moved), truth, atol=1e-9)  # exact data: SVD round-off (~6e-16)
    with pytest.raises(ValueError, match="rigid_fit needs"):
        rigid_fit(pts[:2], moved[:2])


def test_transform_from_closures_rejects_outlier() -> None:
    rng = np.random.default_rng(2)
    maps = _world()
    # Keyframes of each agent: poses in their own map frame; world poses follow from the map frames.
    kf_c3po = {i: pose_from_planar(rng.uniform(0, 5), rng.uniform(0, 5), rng.uniform(-3, 3)) for i in range(5)}
    kf_r2d2 = {i: pose_from_planar(rng.uniform(0, 5), rng.uniform(0, 5), rng.uniform(-3, 3)) for i in range(5)}
    closures = []
    for i in range(4):
        world_a = maps["c3po"] @ kf_c3po[i]
        world_b = maps["r2d2"] @ kf_r2d2[i]
        closures.append(InterAgentClosure("c3po", i, "r2d2", i, invert(world_a) @ world_b))
    # One closure in the opposite direction, one wrong closure.
    closures.append(
        InterAgentClosure("r2d2", 4, "c3po", 4, invert(maps["r2d2"] @ kf_r2d2[4]) @ maps["c3po"] @ kf_c3po[4])
    )
    closures.append(InterAgentClosure("c3po", 0, "r2d2", 1, pose_from_planar(3.0, 1.0, 0.5)))
    result = estimate_agent_transform(
        closures, {"c3po": kf_c3po, "r2d2": kf_r2d2}, {"c3po": np.eye(4)}, "r2d2", min_support=2
    )
    assert result is not None
    transform, support = result
    assert support == 5
    np.testing.assert_allclose(transform, maps["r2d2"], atol=1e-9)  # exact closures: round-off (~2e-15 at 12 m)


def test_no_closure_gives_none() -> None:
    assert estimate_agent_transform([], {}, {"c3po": np.eye(4)}, "r2d2") is None
