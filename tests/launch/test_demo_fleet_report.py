"""The demo's collaborative results from recorded data: the robots' trajectories moved into the fleet frame by their
placements (``fleet_trajectories/``), the fleet ATE with one alignment, and the report's per-pair merge and closures
and per-agent bytes per keyframe."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fleetslam.geometry import invert, pose_from_xyz_rpy
from fleetslam.launch.demo import DemoResult, Monitor, write_fleet_trajectories, write_results
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import transform_msg
from fleetslam.msg.typesys import message_from_dict
from fleetslam.topics import FLEET_TRANSFORM, KEYFRAME_SUMMARIES
from fleetslam.trajectory import Trajectory, read_tum, write_tum

from ..support import wait_until

#: Each robot's map frame in the world (where its camera started): the fleet frame is c3po's.
WORLD_FROM_MAP = {
    "c3po": pose_from_xyz_rpy(-12.0, -7.5, 0.3, -np.pi / 2, 0.0, -np.pi / 2),
    "r2d2": pose_from_xyz_rpy(-7.5, -3.5, 0.3, -np.pi / 2, 0.0, np.pi / 2),
}
STAMPS = np.arange(0.0, 60.0, 0.1)


def _record(out: Path, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Ground truth (camera in the world) and SLAM trajectories (camera in each robot's map, 1 cm noise) of two robots
    driving circles over the same ground; returns the true ``T_fleet_map`` of each."""
    for k, (robot, world_from_map) in enumerate(WORLD_FROM_MAP.items()):
        angle = STAMPS * 0.1 + k * np.pi
        truth = [pose_from_xyz_rpy(-9.0 + 3.0 * np.cos(a), -5.5 + 3.0 * np.sin(a), 0.3, -np.pi / 2, 0.0, a)
                 for a in angle]  # fmt: skip
        slam = [invert(world_from_map) @ t @ pose_from_xyz_rpy(*rng.normal(0.0, 0.01, 3), 0.0, 0.0, 0.0)
                for t in truth]  # fmt: skip
        write_tum(out / "ground_truth" / f"{robot}.txt", Trajectory.from_lists(STAMPS.tolist(), truth))
        write_tum(out / "trajectories" / f"{robot}.txt", Trajectory.from_lists(STAMPS.tolist(), slam))
    fleet_in_world = WORLD_FROM_MAP["c3po"]
    return {robot: invert(fleet_in_world) @ pose for robot, pose in WORLD_FROM_MAP.items()}


def test_fleet_trajectories_are_the_slam_trajectories_moved_by_the_placements(tmp_path: Path) -> None:
    pytest.importorskip("evo")
    true_placement = _record(tmp_path, np.random.default_rng(5))
    placements = {robot: (12.0 * k, pose) for k, (robot, pose) in enumerate(true_placement.items())}
    fleet = write_fleet_trajectories(tmp_path, placements, {"c3po": 0.0, "r2d2": 20.05})
    for robot in ("c3po", "r2d2"):
        written = read_tum(tmp_path / "fleet_trajectories" / f"{robot}.txt")
        slam = read_tum(tmp_path / "trajectories" / f"{robot}.txt")
        np.testing.assert_allclose(written.stamps, slam.stamps)
        np.testing.assert_allclose(written.positions, (true_placement[robot] @ slam.poses)[:, :3, 3], atol=2e-6)
    assert fleet.poses == {"c3po": 600, "r2d2": 600}
    assert fleet.before_placement == {"c3po": 0, "r2d2": 201}  # stamps 0.0 … 20.0 precede r2d2's placement
    first_lines = (tmp_path / "fleet_trajectories" / "r2d2.txt").read_text().splitlines()[:1]
    assert first_lines == ["# r2d2's SLAM camera (optical frame) in the fleet frame; placed at stamp 20.050000: the "
                           "201 poses stamped earlier precede its placement"]  # fmt: skip
    assert fleet.ate is not None and fleet.ate < 0.03  # 1 cm noise per axis
    # One alignment for the fleet: r2d2 placed 0.4 m off shows in the fleet ATE (each robot's own alignment hides it).
    wrong = {**placements, "r2d2": (12.0, pose_from_xyz_rpy(0.4, 0.0, 0.0, 0.0, 0.0, 0.0) @ true_placement["r2d2"])}
    misplaced = write_fleet_trajectories(tmp_path, wrong, {})
    assert misplaced.ate is not None and misplaced.ate > 0.15
    assert misplaced.before_placement == {"c3po": 0, "r2d2": 0}  # no stamp of placement: none said to precede it
    assert "stamp of placement unknown" in (tmp_path / "fleet_trajectories" / "r2d2.txt").read_text()


def _history(agent: str, topic: str, subscriber: str, kilobytes: list[float]) -> list[dict[str, object]]:
    return [{"t": 100.0 + i, "agent": agent, "topic": f"/{agent}/{topic}", "subscriber": subscriber,
             "bandwidth_bps": kb * 1e3, "bytes": int(kb * 1e3), "delivered": 1}
            for i, kb in enumerate(kilobytes)]  # fmt: skip


def test_report_shows_each_pairs_first_merge_and_closures_and_each_agents_bytes_per_keyframe(tmp_path: Path) -> None:
    pytest.importorskip("evo")
    pytest.importorskip("matplotlib")
    true_placement = _record(tmp_path, np.random.default_rng(6))
    placements = {"c3po": (2.0, true_placement["c3po"]), "r2d2": (41.3, true_placement["r2d2"])}
    stamps = {"c3po": 0.0, "r2d2": 30.0}
    history = [
        *_history("c3po", "keyframe_summaries", "/r2d2/slam", [30.0, 45.0]),
        *_history("c3po", "graph_updates", "/r2d2/slam", [1.5, 2.5]),
        *_history("c3po", "graph_updates", "/c3po/mapping", [9.0]),  # its own mapping node: not exchanged
        *_history("c3po", "graph_updates", "/demo_monitor", [9.0]),  # the recorder: not exchanged
        *_history("r2d2", "keyframe_summaries", "/c3po/slam", [60.0]),
        *_history("r2d2", "graph_updates", "/c3po/slam", [4.0]),
    ]
    slam = {"c3po": {"keyframes": "10", "peer_closures_accepted.r2d2": "7", "peer_closures_rejected.r2d2": "2"},
            "r2d2": {"keyframes": "8", "peer_closures_accepted.c3po": "0",
                     "peer_closures_rejected.c3po": "1"}}  # fmt: skip
    result = DemoResult(tmp_path, 90.0, [], history, ate={"c3po": 0.011, "r2d2": 0.012}, slam=slam,
                        placements=placements, placed_stamps=stamps,
                        fleet=write_fleet_trajectories(tmp_path, placements, stamps))  # fmt: skip
    write_results(result)
    lines = (tmp_path / "report.md").read_text().splitlines()
    assert [line for line in lines if line.startswith("## ")] == [
        "## SLAM per robot", "## Fleet frame", "## Fleet trajectories", "## Agent pairs", "## Exchange per agent",
        "## Per agent"]  # fmt: skip
    assert "| c3po ↔ r2d2 | 41 | c3po | 7 | 2 |" in lines  # merged when r2d2, the later, was placed
    assert "| c3po ↔ r2d2 | 41 | r2d2 | 0 | 1 |" in lines
    # c3po → r2d2: 75 kB of summaries and 4 kB of graph updates for 10 keyframes; r2d2 → c3po: 64 kB for 8.
    assert "| c3po | r2d2 | 10 | 75.0 | 4.0 | 7900 |" in lines
    assert "| r2d2 | c3po | 8 | 60.0 | 4.0 | 8000 |" in lines
    assert "| c3po | 600 | 0 | 0.011 |" in lines
    assert "| r2d2 | 600 | 300 | 0.012 |" in lines  # stamps 0.0 … 29.9 precede its placement at 30 s
    fleet_row = next(line for line in lines if line.startswith("| fleet (one alignment) |"))
    assert fleet_row.startswith("| fleet (one alignment) | 1200 | 300 | 0.0")  # 1 cm noise: the fleet ATE is cm
    page = (tmp_path / "report.html").read_text()
    assert "<td>c3po ↔ r2d2</td><td>41</td><td>c3po</td><td>7</td><td>2</td>" in page
    assert "<h2>Exchange per agent</h2>" in page


def test_a_pair_not_merged_says_so(tmp_path: Path) -> None:
    slam = {"c3po": {"keyframes": "4"}, "r2d2": {"keyframes": "3"}}
    result = DemoResult(tmp_path, 30.0, [], [], slam=slam, placements={"c3po": (1.0, np.eye(4))})
    write_results(result)
    lines = (tmp_path / "report.md").read_text().splitlines()
    assert "| c3po ↔ r2d2 | not merged | c3po | — | — |" in lines
    assert "## Exchange per agent" not in lines  # no statistics of the exchanged topics: no table


def test_monitor_keeps_the_first_placements_stamp_the_latest_placement_and_the_bytes_received(
    make_context: Callable[..., Context],
) -> None:
    monitor = Monitor(make_context(), ["c3po", "r2d2"], None)
    slam = Node("slam", context=make_context("r2d2"))
    placement = slam.create_publisher(FLEET_TRANSFORM.type, FLEET_TRANSFORM.name, FLEET_TRANSFORM.qos())
    assert wait_until(lambda: placement.matched_subscriptions > 0, 10.0)
    first, refined = pose_from_xyz_rpy(4.0, 1.0, 0.0, 0.0, 0.0, 0.5), pose_from_xyz_rpy(4.1, 1.0, 0.0, 0.0, 0.0, 0.5)
    placement.publish(transform_msg(first, "fleet", "r2d2/map", 5_250_000_000).transforms[0])
    assert wait_until(lambda: "r2d2" in monitor.placements(), 10.0)
    placement.publish(transform_msg(refined, "fleet", "r2d2/map", 9_000_000_000).transforms[0])
    assert wait_until(lambda: np.allclose(monitor.placements()["r2d2"][1], refined), 10.0)
    assert monitor.placement_stamps() == {"r2d2": pytest.approx(5.25)}  # the first: its poses before it precede it
    # Its peer's statistics of r2d2's keyframe summaries: the bytes of each window are kept.
    summaries = Node("slam", context=make_context("c3po"), statistics_period_s=0.2)
    summaries.create_subscription(KEYFRAME_SUMMARIES.type, KEYFRAME_SUMMARIES.of("r2d2"), lambda m: None)
    sender = slam.create_publisher(KEYFRAME_SUMMARIES.type, KEYFRAME_SUMMARIES.name, KEYFRAME_SUMMARIES.qos())
    assert wait_until(lambda: sender.matched_subscriptions > 0, 10.0)
    sender.publish(message_from_dict(KEYFRAME_SUMMARIES.type, {"agent": "r2d2", "id": 1}))

    def received() -> int:
        with monitor.lock:
            return sum(int(h["bytes"]) for h in monitor.history
                       if h["topic"] == "/r2d2/keyframe_summaries" and h["subscriber"] == "/c3po/slam")  # fmt: skip

    assert wait_until(lambda: received() > 0, 10.0)
    monitor.close()
