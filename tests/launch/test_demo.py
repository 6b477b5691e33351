"""`fleetslam demo` end to end, headless: agents, statistics and the results folder."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from fleetslam.launch.demo import run_demo
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.trajectory import read_tum

from ..support import free_port


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
        assert len(read_tum(run / "trajectories" / f"{robot}.txt")) > 20
        assert len(read_tum(run / "ground_truth" / f"{robot}.txt")) > 20
        assert 0.0 <= result.ate[robot] < 1.0
    assert (run / "recording" / "metadata.yaml").is_file()
    assert (run / "trajectories.png").stat().st_size > 1000 and (run / "bandwidth.png").stat().st_size > 1000
    report = (run / "report.md").read_text()
    assert "ATE RMSE" in report and "/c3po/camera/rgb/image_raw" in report
    assert "<table>" in (run / "report.html").read_text()
    links = {(r["topic"], r["node_sub"]) for r in json.loads((run / "statistics.json").read_text())}
    # Each agent subscribes to the other's graph (the seed's cross-agent subscription).
    assert ("/c3po/graph", "/r2d2/slam") in links and ("/r2d2/graph", "/c3po/slam") in links
