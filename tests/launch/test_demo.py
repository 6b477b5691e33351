"""`fleetslam demo` end to end, headless: agents, statistics and the results folder."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.launch.demo import (
    DemoResult,
    Monitor,
    decoded_stamp_pose,
    odometry_stamp_pose,
    run_demo,
    slam_values,
    write_results,
)
from fleetslam.launch.supervisor import ProcessUsage
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.recording import read_bag
from fleetslam.msg.typesys import get_type, header, message_from_dict, serialize
from fleetslam.trajectory import read_tum

from ..support import free_port, wait_until


def test_headless_demo_writes_results(tmp_path: Path) -> None:
    out = io.StringIO()
    result = run_demo(
        robots=["c3po", "r2d2"], duration_s=8.0, out_dir=tmp_path / "run", router_port=free_port(), headless=True,
        output=out, mode="synthetic",
    )  # fmt: skip
    rows = json.loads((tmp_path / "run" / "statistics.json").read_text())
    links = {(r["topic"], r["node_sub"]) for r in rows}
    # The seed's cross-agent subscription: each agent receives the other's graph.
    assert ("/c3po/graph", "/r2d2/slam") in links and ("/r2d2/graph", "/c3po/slam") in links
    assert all(r["dropped"] == 0 for r in rows)
    assert set(result.per_agent()) == {"c3po", "r2d2"}
    report = (tmp_path / "run" / "report.md").read_text()
    assert "| c3po | /c3po/graph |" in report
    assert (tmp_path / "run" / "bandwidth.png").stat().st_size > 1000
    assert "[demo" in out.getvalue()
    # The inspection report, with no finding recorded (the findings service ran: its file is written).
    assert json.loads((tmp_path / "run" / "findings" / "findings.json").read_text())["findings"] == []
    assert "No findings were recorded" in (tmp_path / "run" / "inspection" / "report.html").read_text()
    assert "[demo] inspection report: " in out.getvalue()


def test_headless_simulated_demo_produces_every_result(tmp_path: Path) -> None:
    """The main job: simulated robots, SLAM, maps, fleet map; every file of the results folder."""
    pytest.importorskip("mujoco")
    out = io.StringIO()
    run = tmp_path / "sim"
    result = run_demo(
        robots=["c3po", "r2d2"], duration_s=25.0, out_dir=run, router_port=free_port(), headless=True, output=out,
    )  # fmt: skip
    for name in ("c3po", "r2d2", "fleet"):
        tree = OccupancyOctree.read(run / "maps" / f"{name}.bt")
        assert tree.num_nodes() > 1000, name
    for robot in ("c3po", "r2d2"):
        final = read_tum(run / "trajectories" / f"{robot}.txt")
        live = read_tum(run / "trajectories_live" / f"{robot}.txt")
        assert len(final) > 20 and len(read_tum(run / "ground_truth" / f"{robot}.txt")) > 20
        # SLAM's own trajectory as the run ended: the frames it tracked (each published live), re-anchored.
        common = set(final.stamps.tolist()) & set(live.stamps.tolist())
        assert len(common) >= 0.9 * max(len(final), len(live)), (len(common), len(final), len(live))
        assert f"[demo] {robot}: final trajectory" in out.getvalue()
        assert 0.0 <= result.ate[robot] < 1.0  # smoke bound (7 and 17 mm measured); accuracy is tests/integration's
        assert 0.0 <= result.ate_live[robot] < 1.0
    assert (run / "recording" / "metadata.yaml").is_file()
    assert (run / "trajectories.png").stat().st_size > 1000 and (run / "bandwidth.png").stat().st_size > 1000
    report = (run / "report.md").read_text()
    assert "ATE RMSE (m), final" in report and "ATE RMSE (m), live" in report
    assert "/c3po/camera/rgb/image_raw" in report
    assert "<table>" in (run / "report.html").read_text()
    links = {(r["topic"], r["node_sub"]) for r in json.loads((run / "statistics.json").read_text())}
    # Each agent receives the other's keyframe summaries and graph updates (collaborative SLAM), not its images.
    for me, peer in (("c3po", "r2d2"), ("r2d2", "c3po")):
        assert (f"/{peer}/keyframe_summaries", f"/{me}/slam") in links, links
        assert (f"/{peer}/graph_updates", f"/{me}/slam") in links, links
        assert (f"/{peer}/keyframes", f"/{me}/slam") not in links


def _diagnostics(agent: str, values: dict[str, str]) -> Any:
    status = get_type("diagnostic_msgs/msg/DiagnosticStatus")
    key_value = get_type("diagnostic_msgs/msg/KeyValue")
    other = status(level=status.OK, name="camera", message="", hardware_id=agent, values=[])
    slam = status(level=status.OK, name="slam", message="tracking", hardware_id=agent,
                  values=[key_value(key=k, value=v) for k, v in values.items()])  # fmt: skip
    return get_type("diagnostic_msgs/msg/DiagnosticArray")(header=header("map", 0), status=[other, slam])


SLAM_VALUES = {"frames_received": "812", "frames_processed": "790", "frames_dropped": "22", "relocalisations": "1",
               "loop_closures": "14", "loops_retracted": "2", "lost_frames": "3", "coasting_frames": "9",
               "keyframes": "203", "odometry_ms_mean": "11.42", "latency_ms_mean": "20.1", "peer_keyframes": "150",
               "peer_closures": "31"}  # fmt: skip


def test_report_tables_per_robot_slam_and_per_process(tmp_path: Path) -> None:
    values = slam_values(_diagnostics("c3po", SLAM_VALUES))
    assert values == SLAM_VALUES
    assert slam_values(get_type("diagnostic_msgs/msg/DiagnosticArray")(header=header("map", 0), status=[])) is None
    processes = [ProcessUsage("demo (router, monitor)", 100, 3.0, 100.0, 250.0),
                 ProcessUsage("c3po/mapping", 101, 9.5, 95.0, 410.4, restarts=1),
                 ProcessUsage("sim", None, 0.0, 0.0, 0.0)]  # fmt: skip
    truth = pose_from_xyz_rpy(4.5, 4.0, 0.0, 0.0, 0.0, np.pi)
    placed = pose_from_xyz_rpy(0.03, 0.04, 0, 0, 0, 0) @ truth  # 5 cm off
    result = DemoResult(tmp_path, 100.0, [], processes=processes, ate={"c3po": 0.0123, "r2d2": 0.02},
                        ate_live={"c3po": 0.0251},
                        slam={"c3po": values, "r2d2": None},
                        placements={"c3po": (2.0, np.eye(4)), "r2d2": (31.4, placed)},
                        true_placements={"c3po": np.eye(4), "r2d2": truth})  # fmt: skip
    write_results(result)
    lines = (tmp_path / "report.md").read_text().splitlines()
    header_row = next(line for line in lines if line.startswith("| robot | frames received"))
    assert header_row.endswith(
        "| odometry ms (mean) | peer keyframes | peer closures | ATE RMSE (m), final | ATE RMSE (m), live |"
    )
    assert "| c3po | 812 | 790 | 22 | 1 | 14 | 2 | 203 | 3 | 9 | 11.42 | 150 | 31 | 0.012 | 0.025 |" in lines
    assert "| r2d2 | — | — | — | — | — | — | — | — | — | — | — | — | 0.020 | — |" in lines  # no diagnostics
    # The fleet frame: when each robot's SLAM placed it, and the placement's error against the true start poses.
    assert "| c3po | 2 | 0.000 | 0.00 |" in lines and "| r2d2 | 31 | 0.050 | 0.00 |" in lines
    assert "| demo (router, monitor) | 100 | 3.0 | 3.0 | 250 | 0 |" in lines
    assert "| c3po/mapping | 101 | 10.0 | 9.5 | 410 | 1 |" in lines
    assert "| sim | — | 0.0 | 0.0 | 0 | 0 |" in lines  # never started
    assert "<td>c3po/mapping</td><td>101</td><td>10.0</td>" in (tmp_path / "report.html").read_text()
    figures = json.loads((tmp_path / "processes.json").read_text())
    assert figures[1] == {"label": "c3po/mapping", "pid": 101, "cpu_percent": 10.0, "cpu_s": 9.5, "wall_s": 95.0,
                          "peak_rss_mib": 410.4, "restarts": 1}  # fmt: skip
    assert [f["label"] for f in figures] == ["demo (router, monitor)", "c3po/mapping", "sim"]


def test_monitor_keeps_each_robots_latest_slam_diagnostics_and_its_odometry(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    monitor = Monitor(make_context(), ["c3po", "r2d2"], tmp_path / "recording")
    slam = Node("slam", context=make_context("c3po"))
    diagnostics = slam.create_publisher("diagnostic_msgs/msg/DiagnosticArray", "slam/diagnostics", QoSProfile(depth=5))
    slam_odometry = slam.create_publisher("nav_msgs/msg/Odometry", "slam/odom", QoSProfile(depth=100))
    assert wait_until(lambda: diagnostics.matched_subscriptions > 0 and slam_odometry.matched_subscriptions > 0, 10.0)
    for frame in range(1, 6):
        diagnostics.publish(_diagnostics("c3po", {**SLAM_VALUES, "frames_processed": str(frame)}))
    for i in range(30):
        pose = {"position": {"x": 0.1 * i}, "orientation": {"w": 1.0}}
        odometry = message_from_dict("nav_msgs/msg/Odometry", {"pose": {"pose": pose}})
        odometry.header = header("odom", 1_000_000_000 + i * 20_000_000)
        slam_odometry.publish(odometry)
    assert wait_until(lambda: monitor.slam_diagnostics().get("c3po", {}).get("frames_processed") == "5", 10.0)
    assert wait_until(lambda: len(monitor.tracks["c3po/slam"]) == 30, 10.0)
    latest = monitor.slam_diagnostics()
    assert set(latest) == {"c3po"}  # r2d2's SLAM published nothing
    assert latest["c3po"]["keyframes"] == "203"
    stamps, poses = monitor.trajectories()["c3po/slam"]
    assert stamps == pytest.approx([1.0 + 0.02 * i for i in range(30)])
    assert poses[:, 0, 3] == pytest.approx([0.1 * i for i in range(30)])
    assert np.allclose(poses[:, :3, :3], np.eye(3))
    assert monitor.trajectories()["r2d2/slam"][1].shape == (0, 4, 4)
    monitor.close()
    recorded = [m.topic for m in read_bag(tmp_path / "recording")]
    assert recorded.count("/c3po/slam/odom") == 30  # recorded as received
    assert "c3po/truth" not in monitor.tracks  # the simulator writes the ground truth itself


@pytest.mark.parametrize("frame_id", ["", "m", "map", "odom", "world_frame"])
@pytest.mark.parametrize("child_frame_id", ["", "b", "base_link", "camera_rgb_optical_frame"])
def test_odometry_stamp_and_pose_are_read_where_cdr_puts_them(frame_id: str, child_frame_id: str) -> None:
    """Strings of every length modulo 4 and 8 move the pose: the reader aligns as CDR does."""
    rng = np.random.default_rng(len(frame_id) * 31 + len(child_frame_id))
    position, quaternion = rng.normal(size=3), rng.normal(size=4)
    msg = message_from_dict("nav_msgs/msg/Odometry", {
        "child_frame_id": child_frame_id,
        "pose": {"pose": {"position": dict(zip("xyz", position.tolist(), strict=True)),
                          "orientation": dict(zip("xyzw", quaternion.tolist(), strict=True))},
                 "covariance": rng.normal(size=36).tolist()},
    })  # fmt: skip
    msg.header = header(frame_id, 1_700_000_123_456_789_012)
    data = serialize(msg, "nav_msgs/msg/Odometry")
    stamp, pose = odometry_stamp_pose(data)
    assert stamp == pytest.approx(1_700_000_123.456789012)
    np.testing.assert_array_equal(pose, np.concatenate([position, quaternion]))
    decoded = decoded_stamp_pose(data)  # the full decode, for payloads the reader does not take
    assert decoded[0] == pytest.approx(stamp) and np.array_equal(decoded[1], pose)


def test_secured_demo_runs_under_mutual_tls_and_access_control(tmp_path: Path) -> None:
    """`fleetslam demo --secure`: every process joins by mutual TLS under the router's access control, and the demo
    still does its job (maps of every robot and the fleet, trajectories)."""
    pytest.importorskip("mujoco")
    import shutil

    if shutil.which("openssl") is None:
        pytest.skip("the openssl command makes the certificates")
    out = io.StringIO()
    run = tmp_path / "secure"
    port = free_port()
    result = run_demo(robots=["c3po", "r2d2"], duration_s=25.0, out_dir=run, router_port=port, headless=True,
                      output=out, secure=True)  # fmt: skip
    assert f"router on tls/localhost:{port}" in out.getvalue()
    assert (run / "keys" / "c3po" / "cert.pem").is_file()
    for name in ("c3po", "r2d2", "fleet"):
        assert OccupancyOctree.read(run / "maps" / f"{name}.bt").num_nodes() > 1000, name
    for robot in ("c3po", "r2d2"):
        assert len(read_tum(run / "trajectories" / f"{robot}.txt")) > 20
        assert 0.0 <= result.ate[robot] < 1.0
