from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fleetslam.geometry import invert, pose_from_planar, pose_from_xyz_rpy
from fleetslam.slam.backend import PoseGraph, information_from_std


def _square_loop(n: int = 40) -> list[np.ndarray]:
    return [
        pose_from_planar(
            2.0 * np.cos(2 * np.pi * i / n), 2.0 * np.sin(2 * np.pi * i / n), 2 * np.pi * i / n + np.pi / 2
        )
        for i in range(n)
    ]


def _drifting_graph(truth: list[np.ndarray]) -> tuple[PoseGraph, np.ndarray]:
    graph = PoseGraph(optimize_max_error=3.0)
    info = information_from_std(0.01, np.radians(0.5))
    drift = pose_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, np.radians(0.4))  # a biased gyro
    pose = truth[0].copy()
    graph.add_node(0, pose)
    for i in range(1, len(truth)):
        step = invert(truth[i - 1]) @ truth[i] @ drift
        pose = pose @ step
        graph.add_node(i, pose)
        graph.add_odometry(i - 1, i, step, info)
    return graph, info


def _ate(poses: dict[int, np.ndarray], truth: list[np.ndarray]) -> float:
    return float(np.sqrt(np.mean([np.sum((poses[i][:3, 3] - t[:3, 3]) ** 2) for i, t in enumerate(truth)])))


def test_loop_closure_reduces_ate_of_a_drifting_trajectory() -> None:
    truth = _square_loop()
    graph, _ = _drifting_graph(truth)
    before = _ate(graph.optimize(), truth)
    loop = invert(truth[0]) @ truth[-1]
    assert graph.add_loop(0, len(truth) - 1, loop, information_from_std(0.01, np.radians(0.5)))
    after = _ate(graph.optimize(), truth)
    assert before > 0.2  # 0.4°/step gyro bias over 40 steps: 35 cm
    assert after < before / 4  # the loop leaves ~1 cm (9 mm measured)
    assert [c.kind for c in graph.constraints()].count("loop") == 1


def test_outlier_loop_is_rejected() -> None:
    truth = _square_loop()
    graph, info = _drifting_graph(truth)
    poses_before = graph.optimize()
    wrong = invert(truth[0]) @ truth[20]  # claims the last pose is where pose 20 is
    assert not graph.add_loop(0, len(truth) - 1, wrong, info)
    assert all(c.kind == "odometry" for c in graph.constraints())
    np.testing.assert_allclose(graph.optimize()[39], poses_before[39], atol=1e-9)


def _gtsam_data(name: str) -> Path | None:
    import gtsam

    try:
        return Path(gtsam.findExampleDataFile(name))
    except (RuntimeError, IndexError, ValueError):
        return None


def test_real_pose_graph_dataset_optimises() -> None:
    import gtsam

    path = _gtsam_data("pose3example.txt")
    if path is None:
        pytest.skip("gtsam example data pose3example.txt not shipped with this gtsam build")
    graph_data, initial = gtsam.readG2o(str(path), True)
    graph = PoseGraph(robust_kernel="none", optimize_max_error=0.0)
    keys = sorted(initial.keys())
    for k in keys:
        graph.add_node(int(k), initial.atPose3(k).matrix())
    for i in range(graph_data.size()):
        factor = graph_data.at(i)
        if not isinstance(factor, gtsam.BetweenFactorPose3):
            continue
        a, b = factor.keys()
        info_gtsam = np.linalg.inv(factor.noiseModel().covariance())
        perm = [3, 4, 5, 0, 1, 2]
        info = info_gtsam[np.ix_(perm, perm)]
        measured = factor.measured().matrix()
        if b == a + 1:
            graph.add_odometry(int(a), int(b), measured, info)
        else:
            graph.add_loop(int(a), int(b), measured, info)
    ours = graph.optimize_full()
    reference = gtsam.GaussNewtonOptimizer(_with_prior(graph_data, initial, keys[0]), initial).optimize()
    for k in keys:
        # Same minimum, different optimisers and stopping rules (LM vs Gauss-Newton): 1.5 mm apart at most.
        np.testing.assert_allclose(ours[int(k)][:3, 3], reference.atPose3(k).translation(), atol=5e-3)


def _with_prior(graph_data: object, initial: object, key: int) -> object:
    import gtsam

    graph = gtsam.NonlinearFactorGraph(graph_data)
    graph.add(gtsam.PriorFactorPose3(key, initial.atPose3(key), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))  # type: ignore[attr-defined]
    return graph
