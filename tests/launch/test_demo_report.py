"""The demo's report (report.md, report.html) rendered from fixed data: every section, table and figure as before
the report went through templates (the expected files were written by the hand-written renderer it replaced)."""

from __future__ import annotations

import html.parser
from pathlib import Path

import numpy as np
import pytest

from fleetslam.launch.demo import DemoResult, write_results
from fleetslam.launch.supervisor import ProcessUsage
from fleetslam.middleware.stats_table import StatsRow

DATA = Path(__file__).parent / "data"


def _row(agent: str, topic: str, sub: str, kbps: float, hz: float, delivered: int, dropped: int) -> StatsRow:
    return StatsRow(agent=agent, topic=topic, type="fleetslam_msgs/msg/KeyframeGraph", node_pub=f"/{agent}/slam",
                    node_sub=sub, window_s=1.0, bandwidth_bps=kbps * 1e3, delivered=delivered, dropped=dropped,
                    errors=0, rate_hz=hz, age_mean_ms=1.234, age_std_ms=0.5, age_max_ms=3.0, period_mean_ms=100.0,
                    period_std_ms=1.0, period_max_ms=120.0, stamp_ns=1_700_000_000_000_000_000)  # fmt: skip


def report_data(out: Path) -> DemoResult:
    """A run's figures, fixed: statistics of two agents, two maps, SLAM per robot, processes, bandwidth history."""
    from fleetslam.mapping.octree import OccupancyOctree

    (out / "maps").mkdir(parents=True)
    rng = np.random.default_rng(7)
    for name, shift in (("c3po", 0.0), ("fleet", 2.0)):
        tree = OccupancyOctree(0.1)
        points = rng.uniform(-1.0, 1.0, (400, 3)) + np.array([shift + 2.0, 0.0, 0.5])
        tree.insert_point_cloud(points, np.array([shift, 0.0, 0.5]))
        tree.write_binary(out / "maps" / f"{name}.bt")
    rows = [_row("c3po", "/c3po/graph", "/r2d2/slam", 12.345, 2.0, 20, 0),
            _row("r2d2", "/r2d2/graph", "/c3po/slam", 3.2, 1.5, 15, 2),
            _row("r2d2", "/r2d2/camera/rgb/image_raw", "/r2d2/slam", 2304.0, 10.0, 100, 1)]  # fmt: skip
    history = [{"t": 100.0 + i, "agent": r.agent, "topic": r.topic, "subscriber": r.node_sub,
                "bandwidth_bps": r.bandwidth_bps * (1 + 0.1 * i)} for i in range(3) for r in rows]  # fmt: skip
    processes = [ProcessUsage("demo (router & monitor)", 100, 3.0, 100.0, 250.0),
                 ProcessUsage("c3po/mapping", 101, 9.5, 95.0, 410.4, restarts=1),
                 ProcessUsage("sim", None, 0.0, 0.0, 0.0)]  # fmt: skip
    slam = {"c3po": {"frames_received": "812", "frames_processed": "790", "frames_dropped": "22",
                     "relocalisations": "1", "loop_closures": "14", "loops_retracted": "2", "keyframes": "203",
                     "lost_frames": "3", "coasting_frames": "9", "odometry_ms_mean": "11.42"},
            "r2d2": None}  # fmt: skip
    return DemoResult(out, 61.4, rows, history, ate={"c3po": 0.0123, "r2d2": 0.02}, ate_live={"c3po": 0.0251},
                      plots=[out / "trajectories.png", None], processes=processes, slam=slam)  # fmt: skip


class _Elements(html.parser.HTMLParser):
    """An HTML page as (tag, attributes, text) per element, entities resolved: what a browser shows."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.items: list[tuple[str, tuple[tuple[str, str | None], ...], str]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.items.append((tag, tuple(attrs), ""))

    def handle_data(self, data: str) -> None:
        if data.strip():
            tag, attrs, text = self.items[-1]
            self.items[-1] = (tag, attrs, text + data)


def _elements(page: str) -> list[tuple[str, tuple[tuple[str, str | None], ...], str]]:
    parser = _Elements()
    parser.feed(page)
    return parser.items


def test_report_renders_the_same_sections_tables_and_figures(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    pytest.importorskip("numba")
    write_results(report_data(tmp_path))
    markdown = (tmp_path / "report.md").read_text()
    assert markdown == (DATA / "demo_report.md").read_text()
    lines = markdown.splitlines()
    assert [line for line in lines if line.startswith("#")] == [
        "# fleetslam demo report", "## Maps", "## SLAM per robot", "## Processes", "## Per agent"]  # fmt: skip
    assert "| r2d2 | /r2d2/graph | /r2d2/slam → /c3po/slam | 3.2 | 1.5 | 15 | 2 | 1.23 ± 0.50 |" in lines
    assert "| r2d2 | 2307.2 | 115 | 3 |" in lines  # per agent: the sum of its rows
    assert lines[-3:] == ["![trajectories](trajectories.png)", "", "![bandwidth](bandwidth.png)"]
    page = (tmp_path / "report.html").read_text()
    assert _elements(page) == _elements((DATA / "demo_report.html").read_text())
    assert "<td>demo (router &amp; monitor)</td>" in page  # escaped once, not twice
    tables = _elements(page)
    assert sum(tag == "table" for tag, _, _ in tables) == 5
    assert ("img", (("alt", "bandwidth"), ("src", "bandwidth.png")), "") in tables
    assert (tmp_path / "bandwidth.png").stat().st_size > 1000
