"""`fleetslam demo` end to end, headless: agents, statistics and the results folder."""

from __future__ import annotations

import io
import json
from pathlib import Path

from fleetslam.launch.demo import run_demo

from ..support import free_port


def test_headless_demo_writes_results(tmp_path: Path) -> None:
    out = io.StringIO()
    result = run_demo(
        robots=["c3po", "r2d2"], duration_s=8.0, out_dir=tmp_path / "run", router_port=free_port(), headless=True,
        output=out,
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
