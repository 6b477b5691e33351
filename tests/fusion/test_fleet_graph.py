"""The fleet back-end's joint optimisation (real GTSAM) on synthetic, exact geometry."""

from __future__ import annotations

import numpy as np

from fleetslam.fusion.alignment import rigid_fit
from fleetslam.fusion.fleet_graph import ClosureReport, FleetGraph
from fleetslam.fusion.graph_exchange import GraphUpdate
from fleetslam.geometry import invert, make_pose, pose_from_planar, rotation_angle, so3_exp, so3_log

STEPS = 41
"""Keyframes per agent, 0.5 m apart along the same 20 m aisle."""
R2D2_MAP = pose_from_planar(5.0, -3.0, 0.7)
"""r2d2's map frame in the fleet frame (c3po's map frame)."""


def _truth() -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """True camera poses in the fleet frame: c3po along the aisle, r2d2 along it 0.3 m beside."""
    c3po = {i: pose_from_planar(0.5 * i, 0.0, 0.0) for i in range(STEPS)}
    r2d2 = {i: pose_from_planar(0.5 * i, 0.3, 0.0) for i in range(STEPS)}
    return c3po, r2d2


def _drifted(truth: dict[int, np.ndarray], frame: np.ndarray, yaw_per_step: float) -> dict[int, np.ndarray]:
    """An agent's own poses in its map frame ``frame``: the true steps, each with a small yaw error."""
    own = {0: invert(frame) @ truth[0]}
    error = pose_from_planar(0.0, 0.0, yaw_per_step)
    for i in range(1, STEPS):
        own[i] = own[i - 1] @ invert(truth[i - 1]) @ truth[i] @ error
    return own


def _update(poses: dict[int, np.ndarray], closures: list[ClosureReport], epoch: int) -> GraphUpdate[ClosureReport]:
    return GraphUpdate(1, True, dict(poses), {i: float(i) for i in poses}, closures, epoch)


def _closures(
    c3po: dict[int, np.ndarray], r2d2: dict[int, np.ndarray], ids: list[int], epoch: int
) -> list[ClosureReport]:
    """r2d2's keyframe j sees c3po's keyframe j (exact relative pose), as r2d2 reports it."""
    return [ClosureReport("r2d2", j, "c3po", j, invert(r2d2[j]) @ c3po[j], epoch) for j in ids]


def _beside_error(c3po: dict[int, np.ndarray], r2d2: dict[int, np.ndarray]) -> list[float]:
    """How far r2d2's keyframe j is from where it truly is relative to c3po's keyframe j (0.3 m to its left), all
    along the aisle: a doubled wall in the fleet map where this is not 0."""
    return [float(np.linalg.norm((invert(c3po[j]) @ r2d2[j])[:3, 3] - [0.0, 0.3, 0.0])) for j in range(STEPS)]


def _fleet_ate(placed: list[dict[int, np.ndarray]], truth: list[dict[int, np.ndarray]]) -> float:
    """RMSE of all agents' keyframe positions after one rigid alignment of them all to the truth (COVINS style)."""
    estimate = np.array([poses[i][:3, 3] for poses in placed for i in sorted(poses)])
    true = np.array([poses[i][:3, 3] for poses in truth for i in sorted(poses)])
    T = rigid_fit(estimate, true)
    return float(np.sqrt(np.mean(np.sum((estimate @ T[:3, :3].T + T[:3, 3] - true) ** 2, axis=1))))


ENDS = [0, 2, 4, 6, 34, 36, 38, 40]
"""Where the two agents recognised each other: both ends of the aisle."""


def test_joint_optimisation_corrects_a_drifted_agent() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    fleet.apply("c3po", _update(c3po, [], epoch=11))
    fleet.apply("r2d2", _update(_drifted(r2d2, R2D2_MAP, np.radians(0.3)), _closures(c3po, r2d2, ENDS, 11), 22))
    solution = fleet.solve()
    assert solution is not None and set(solution.placements) == {"c3po", "r2d2"}
    assert solution.robust and len(solution.kept) == len(ENDS) and not solution.rejected
    own = fleet.agents["r2d2"].mirror.poses
    rigid = fleet.connected()["r2d2"]  # the pairwise closures' rigid fit: what an agent alone would place it by
    rigidly = {i: rigid @ own[i] for i in own}
    joint = solution.placements["r2d2"]
    # 0.3° of yaw per 0.5 m step bends r2d2's 20 m aisle by 12°: no rigid placement fits both ends.
    rigid_beside, joint_beside = _beside_error(c3po, rigidly), _beside_error(solution.placements["c3po"].poses,
                                                                             joint.poses)  # fmt: skip
    assert np.mean(rigid_beside) > 0.15 and np.max(rigid_beside) > 0.3
    # The same walls land on each other, within a map voxel (5 cm): the keyframes between two solved ones (every
    # 5th) follow their corrections, interpolated.
    assert np.max(joint_beside) < 0.05, joint_beside
    # Which of the two drifted nothing tells (both chains are odometry): the joint solution bends both by half,
    # still a better fleet map against the truth.
    rigid_ate = _fleet_ate([c3po, rigidly], [c3po, r2d2])
    joint_ate = _fleet_ate([solution.placements["c3po"].poses, joint.poses], [c3po, r2d2])
    assert joint_ate < 0.6 * rigid_ate, (joint_ate, rigid_ate)
    # The fleet frame is c3po's map frame: its placement is the identity, whatever the solve did to its chain.
    np.testing.assert_allclose(solution.placements["c3po"].T_fleet_map, np.eye(4), atol=1e-9)
    # The agent's placement is the rigid fit of its corrected keyframes to its own: near its true map frame.
    assert np.linalg.norm(joint.T_fleet_map[:3, 3] - R2D2_MAP[:3, 3]) < 0.5
    assert fleet.solve() is None  # nothing changed: no solve


def test_a_wrong_closure_on_repeated_structure_is_rejected_while_odometry_stays() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    own_r2d2 = _drifted(r2d2, R2D2_MAP, 0.0)
    closures = _closures(c3po, r2d2, ENDS, 11)
    # The shelf four keyframes (2 m) on looks the same: r2d2's keyframe 20 "sees" c3po's 24 as if it were its 20.
    closures.append(ClosureReport("r2d2", 20, "c3po", 24, invert(r2d2[20]) @ c3po[20], 11))
    fleet.apply("c3po", _update(c3po, [], epoch=11))
    fleet.apply("r2d2", _update(own_r2d2, closures, 22))
    solution = fleet.solve()
    assert solution is not None and solution.robust
    assert [c.key for c in solution.rejected] == [("c3po", 24, "r2d2", 20)]
    assert len(solution.kept) == len(ENDS)
    placed = solution.placements["r2d2"].poses
    assert np.linalg.norm(placed[20][:3, 3] - r2d2[20][:3, 3]) < 0.01  # not pulled 2 m towards the wrong shelf
    # Odometry (known inliers) holds exactly: consecutive corrected keyframes keep their own relative poses.
    for i in (19, 20):
        step = invert(invert(placed[i]) @ placed[i + 1]) @ (invert(own_r2d2[i]) @ own_r2d2[i + 1])
        assert np.linalg.norm(step[:3, 3]) < 1e-3 and rotation_angle(step) < 1e-3


def test_new_keyframes_reuse_the_kept_closures_without_gnc() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    own = _drifted(r2d2, R2D2_MAP, 0.0)
    fleet.apply("c3po", GraphUpdate(1, False, {i: c3po[i] for i in range(STEPS - 1)}, {}, [], 11))
    fleet.apply("r2d2", _update(own, _closures(c3po, r2d2, ENDS[:-1], 11), 22))
    assert fleet.solve() is not None
    fleet.apply("c3po", GraphUpdate(2, False, {STEPS - 1: c3po[STEPS - 1]}, {STEPS - 1: 40.0}, [], 11))
    solution = fleet.solve()
    assert solution is not None and not solution.robust  # the same closures: plain LM, warm-started
    np.testing.assert_allclose(solution.placements["c3po"].poses[STEPS - 1], c3po[STEPS - 1], atol=1e-3)


def test_warm_solves_take_one_step_each_and_converge_to_the_full_solve() -> None:
    c3po, r2d2 = _truth()
    bent = _drifted(r2d2, R2D2_MAP, np.radians(0.4))
    fleets = {}
    for iterations in (1, 20):
        fleet = fleets[iterations] = FleetGraph(warm_iterations=iterations)
        fleet.apply("c3po", _update(c3po, [], epoch=11))
        fleet.apply("r2d2", _update(_drifted(r2d2, R2D2_MAP, np.radians(0.1)), _closures(c3po, r2d2, ENDS, 11), 22))
        assert fleet.solve() is not None
        # r2d2 re-optimised its own graph (it bent more): every keyframe of it moves; the closures stay.
        fleet.apply("r2d2", GraphUpdate(2, False, bent, {i: float(i) for i in bent}, [], 22))
    full = fleets[20].solve()
    assert full is not None and fleets[20].solve() is None  # converged in that one solve
    warm = fleets[1]
    solves = 0
    while warm.solve() is not None:
        solves += 1
        assert solves < 10, "the warm solves never converged"
    assert solves >= 2  # one step did not reach the optimum: the next solve went on from there
    for agent in ("c3po", "r2d2"):
        np.testing.assert_allclose(warm.solution[agent].stack, full.placements[agent].stack, atol=1e-5)


def test_an_agent_that_restarts_is_dropped_and_added_again() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    fleet.apply("c3po", _update(c3po, [], epoch=11))
    fleet.apply("r2d2", _update(_drifted(r2d2, R2D2_MAP, 0.0), _closures(c3po, r2d2, ENDS, 11), 22))
    solution = fleet.solve()
    assert solution is not None and "r2d2" in solution.placements
    # r2d2 restarts its SLAM somewhere else: a new epoch, a new map frame, no closures yet.
    restarted_map = pose_from_planar(-4.0, 6.0, -1.2)
    new_run = _drifted(r2d2, restarted_map, 0.0)
    assert fleet.apply("r2d2", _update({i: new_run[i] for i in range(10)}, [], 33))
    assert fleet.restarts("r2d2") == 1
    solution = fleet.solve()
    assert solution is not None and set(solution.placements) == {"c3po"}  # not placed by its old run's closures
    # c3po's closures with r2d2's old run (to_epoch 22) do not count for the new run.
    stale = [ClosureReport("c3po", j, "r2d2", j, invert(c3po[j]) @ r2d2[j], 22) for j in (0, 2, 4)]
    fleet.apply("c3po", GraphUpdate(2, False, {}, {}, stale, 11))
    assert not fleet.closures()
    # The new run recognises c3po: placed again, in its new frame.
    fleet.apply("r2d2", GraphUpdate(2, False, {i: new_run[i] for i in range(10, STEPS)}, {},
                                    _closures(c3po, r2d2, ENDS, 11), 33))  # fmt: skip
    solution = fleet.solve()
    assert solution is not None and set(solution.placements) == {"c3po", "r2d2"}
    np.testing.assert_allclose(solution.placements["r2d2"].T_fleet_map, restarted_map, atol=1e-3)


def test_closures_reported_by_both_agents_count_once_and_a_gap_asks_for_the_full_graph() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    both = [ClosureReport("c3po", j, "r2d2", j, invert(c3po[j]) @ r2d2[j], 22) for j in ENDS]
    fleet.apply("c3po", _update(c3po, both, epoch=11))
    fleet.apply("r2d2", _update(_drifted(r2d2, R2D2_MAP, 0.0), _closures(c3po, r2d2, ENDS, 11), 22))
    assert len(fleet.closures()) == len(ENDS)
    assert not fleet.apply("c3po", GraphUpdate(3, False, {}, {}, [], 11))  # sequence 2 is missing


def test_the_fleet_frame_follows_the_first_agent_as_agents_appear() -> None:
    c3po, r2d2 = _truth()
    fleet = FleetGraph()
    own_r2d2 = _drifted(r2d2, R2D2_MAP, 0.0)
    fleet.apply("r2d2", _update(own_r2d2, [], epoch=22))  # heard first: the fleet frame is r2d2's map frame for now
    solution = fleet.solve()
    assert solution is not None and set(solution.placements) == {"r2d2"}
    np.testing.assert_allclose(solution.placements["r2d2"].T_fleet_map, np.eye(4), atol=1e-6)
    fleet.apply("c3po", _update(c3po, [], epoch=11))  # c3po comes first alphabetically: its frame is the fleet's
    fleet.apply("r2d2", GraphUpdate(2, False, {}, {}, _closures(c3po, r2d2, ENDS, 11), 22))
    solution = fleet.solve()
    assert solution is not None and set(solution.placements) == {"c3po", "r2d2"}
    np.testing.assert_allclose(solution.placements["c3po"].T_fleet_map, np.eye(4), atol=1e-3)
    np.testing.assert_allclose(solution.placements["r2d2"].T_fleet_map, R2D2_MAP, atol=1e-3)


def test_many_agents_admitted_at_once_are_judged_a_few_per_solve_within_the_budget() -> None:
    """Eight agents recognise the reference at once (their first closures arrive together, as 16 copies of a run do
    in ``benchmarks/fleet_backend.py``): one GNC over all of them would hold every agent's new keyframes back while it
    runs, so each solve judges only as many agents as ``gnc_budget`` variables hold, and the others wait."""
    c3po, _ = _truth()
    rng = np.random.default_rng(7)
    names = [f"r2d2_{k}" for k in range(8)]
    frames = {name: pose_from_planar(*rng.uniform(-10.0, 10.0, 2), rng.uniform(-np.pi, np.pi)) for name in names}
    truths = {name: {i: pose_from_planar(0.5 * i, 0.3 * (k + 1), 0.0) for i in range(STEPS)}
              for k, name in enumerate(names)}  # fmt: skip

    def fleet_with(budget: int) -> FleetGraph:
        fleet = FleetGraph(reference="c3po", gnc_budget=budget)
        fleet.apply("c3po", _update(c3po, [], epoch=11))
        for name in names:
            truth = truths[name]
            closures = [ClosureReport(name, j, "c3po", j, invert(truth[j]) @ c3po[j], 11) for j in ENDS]
            if name == names[3]:  # the shelf 2 m on looks the same: its keyframe 20 "sees" c3po's 24 as its 20
                closures.append(ClosureReport(name, 20, "c3po", 24, invert(truth[20]) @ c3po[20], 11))
            fleet.apply(name, _update(_drifted(truth, frames[name], 0.0), closures, 22))
        return fleet

    unbounded = fleet_with(10_000).solve()  # all at once: the work one solve would do without the budget
    assert unbounded is not None and len(unbounded.placements) == 9 and not unbounded.pending
    budget = 64  # the reference and two agents: 21 + 2 × 20 variables (every 5th, the newest 10, the closures')
    assert unbounded.gnc_variables > 2.5 * budget
    fleet = fleet_with(budget)
    solutions = []
    while (solution := fleet.solve()) is not None:
        solutions.append(solution)
        assert solution.robust and 0 < solution.gnc_variables <= budget  # every solve's GNC within the budget
        assert len(solutions) <= 5, "8 agents, 2 a solve: 4 solves, and one to spare"
    placed = [len(s.placements) for s in solutions]
    assert placed[0] == 3 and placed == sorted(placed) and placed[-1] == 9, placed
    assert len(solutions[0].pending) == 6 * len(ENDS) + 1  # the others' closures wait, unused
    final = solutions[-1]
    assert not final.pending and fleet.solve() is None  # all judged: nothing left to do
    # As robust as one GNC over everything: the wrong closure rejected, every right one kept, the same placements.
    assert [c.key for c in final.rejected] == [("c3po", 24, names[3], 20)]
    assert [c.key for c in unbounded.rejected] == [("c3po", 24, names[3], 20)]
    assert len(final.kept) == len(unbounded.kept) == 8 * len(ENDS)
    for name in names:
        np.testing.assert_allclose(final.placements[name].T_fleet_map, frames[name], atol=1e-3)
        np.testing.assert_allclose(unbounded.placements[name].T_fleet_map, frames[name], atol=1e-3)
    # One more closure of one agent: judged with as much of the fleet free as the budget holds (all of it, when it
    # fits; else the reference, the agent and one neighbour), the others held.
    truth = truths[names[0]]
    closure = ClosureReport(names[0], 10, "c3po", 10, invert(truth[10]) @ c3po[10], 11)
    late = GraphUpdate(2, False, {}, {}, [closure], 22)
    for graph, most in ((fleet, budget), (fleet_with(10_000), 10_000)):
        if graph is not fleet:
            assert graph.solve() is not None
        graph.apply(names[0], late)
        solution = graph.solve()
        assert solution is not None and solution.robust and len(solution.kept) == 8 * len(ENDS) + 1
        assert solution.gnc_variables == (61 if most == budget else unbounded.gnc_variables)  # keyframe 10 was one


def test_an_imprecise_closure_with_its_covariance_weighs_less() -> None:
    c3po, r2d2 = _truth()
    own_r2d2 = _drifted(r2d2, R2D2_MAP, 0.0)
    precise = np.diag([0.01**2] * 3 + [0.005**2] * 3)
    loose = np.diag([0.12**2] * 3 + [0.03**2] * 3)
    # A closure 8 cm off sideways at keyframe 20, as a far patch of inliers gives one.
    off = invert(r2d2[20]) @ c3po[20] @ pose_from_planar(0.0, 0.08, 0.0)

    def solve(with_covariance: bool) -> float:
        closures = [ClosureReport("r2d2", j, "c3po", j, invert(r2d2[j]) @ c3po[j], 11,
                                  precise if with_covariance else None) for j in ENDS]  # fmt: skip
        closures.append(ClosureReport("r2d2", 20, "c3po", 20, off, 11, loose if with_covariance else None))
        fleet = FleetGraph()
        fleet.apply("c3po", _update(c3po, [], epoch=11))
        fleet.apply("r2d2", _update(own_r2d2, closures, 22))
        solution = fleet.solve()
        assert solution is not None and len(solution.kept) == len(ENDS) + 1  # GNC keeps it either way
        return max(_beside_error(solution.placements["c3po"].poses, solution.placements["r2d2"].poses))

    # With one sigma for every closure it counts as much as each true one and bends the aisle towards it.
    assert solve(with_covariance=False) > 0.03  # 5 cm here, against 1.4 cm with the covariances
    assert solve(with_covariance=True) < 0.4 * solve(with_covariance=False)


def test_a_closure_reported_by_the_other_agent_keeps_its_covariance() -> None:
    relative = pose_from_planar(1.0, 0.4, 0.6) @ make_pose(so3_exp([0.05, -0.02, 0.0]), [0.0, 0.0, 0.1])
    xi = np.array([0.01, -0.02, 0.005, 0.003, 0.001, -0.002])  # (translation, rotation)
    covariance = np.outer(xi, xi) + 1e-10 * np.eye(6)
    # r2d2 reports it: the fleet graph orients it from c3po (the first by name), inverted.
    closure = ClosureReport("r2d2", 3, "c3po", 5, relative, 11, covariance).oriented
    np.testing.assert_allclose(closure.relative, invert(relative))
    assert closure.covariance is not None
    # The perturbation relative·exp(ξ) seen from the other side: inverse(relative·exp(ξ)) = inverse(relative)·exp(η).
    step = 1e-4
    perturbed = relative @ make_pose(so3_exp(step * xi[3:]), step * xi[:3])
    difference = relative @ invert(perturbed)  # = exp(η)
    eta = np.concatenate([difference[:3, 3], so3_log(difference[:3, :3])]) / step
    np.testing.assert_allclose(closure.covariance, np.outer(eta, eta) + 1e-10 * np.eye(6), atol=2e-7)
