"""`fleetslam demo`: the fleet on one machine, with the operator console and live network statistics.

Today the demo runs the distributed-SLAM framework's own experiment: a router (the discovery service), agents
c3po and r2d2 in their own processes and namespaces, each publishing its keyframe graph and subscribing to the
other's, the console in the browser and `/statistics` from every subscription. The agents are synthetic
(``fleetslam.launch.example_agent``) until the simulated plant, SLAM and mapping nodes replace them.
At the end it writes ``DIR/statistics.json``, ``DIR/report.md`` and ``DIR/bandwidth.png``.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from fleetslam.launch.description import ProcessSpec, RestartPolicy
from fleetslam.launch.supervisor import Supervisor
from fleetslam.middleware import Context, Node, QoSProfile, Router
from fleetslam.middleware.stats_table import StatsRow, StatsTable
from fleetslam.station.server import StationServer

log = logging.getLogger(__name__)

#: Where each demo robot drives (centre of its circle), so the two agents' maps sit side by side.
ROBOT_CENTERS = [(0.0, 0.0), (8.0, 0.0), (0.0, 8.0), (8.0, 8.0)]


@dataclass
class DemoResult:
    """What a demo run measured."""

    out_dir: Path
    duration_s: float
    rows: list[StatsRow]
    history: list[dict[str, Any]] = field(default_factory=list)

    def per_agent(self) -> dict[str, dict[str, float]]:
        totals: dict[str, dict[str, float]] = {}
        for row in self.rows:
            t = totals.setdefault(row.agent, {"bandwidth_bps": 0.0, "delivered": 0, "dropped": 0})
            t["bandwidth_bps"] += row.bandwidth_bps
            t["delivered"] += row.delivered
            t["dropped"] += row.dropped
        return totals


def _agent_processes(robots: list[str], router: str) -> list[ProcessSpec]:
    processes = []
    for i, robot in enumerate(robots):
        peers = [r for r in robots if r != robot]
        cx, cy = ROBOT_CENTERS[i % len(ROBOT_CENTERS)]
        processes.append(
            ProcessSpec(
                label=f"{robot}/agent",
                host="localhost",
                argv=[
                    sys.executable,
                    "-m",
                    "fleetslam.launch.example_agent",
                    "--peers",
                    *peers,
                    "--center",
                    str(cx),
                    str(cy),
                ],
                environment={
                    "FLEETSLAM_ROUTER": router,
                    "FLEETSLAM_AGENT": robot,
                    "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0",
                },
                restart=RestartPolicy(initial_backoff_s=1.0),
            )
        )
    return processes


def run_demo(
    *,
    robots: list[str],
    duration_s: float | None,
    out_dir: Path,
    port: int = 8080,
    router_port: int = 7447,
    headless: bool = False,
    output: TextIO = sys.stdout,
) -> DemoResult:
    """Run the demo until ``duration_s`` passes (None: until Ctrl-C), then write the results to ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{router_port}"
    table = StatsTable(stale_s=1e9)
    history: list[dict[str, Any]] = []
    lock = threading.Lock()
    with Router([endpoint]):
        supervisor = Supervisor(_agent_processes(robots, endpoint), output=open(out_dir / "agents.log", "w"))  # noqa: SIM115
        with Context(router=endpoint, listen="tcp/127.0.0.1:0", namespace="/") as ctx:
            monitor = Node("demo_monitor", context=ctx, statistics_period_s=0)

            def on_statistics(msg: Any) -> None:
                with lock:
                    row = table.update(msg)
                    history.append({"t": time.time(), "agent": row.agent, "topic": row.topic,
                                    "subscriber": row.node_sub, "bandwidth_bps": row.bandwidth_bps})  # fmt: skip

            monitor.create_subscription(
                "fleetslam_msgs/msg/TopicStatistics", "/statistics", on_statistics, QoSProfile(depth=1000)
            )
            station = None
            if not headless:
                station = StationServer(ctx, port=port)
                station.start()
                print(f"operator console: {station.url}", file=output, flush=True)
            start = time.monotonic()
            supervisor_thread = threading.Thread(target=supervisor.run, kwargs={"poll_interval_s": 0.2}, daemon=True)
            supervisor_thread.start()
            try:
                while duration_s is None or time.monotonic() - start < duration_s:
                    time.sleep(1.0)
                    elapsed = time.monotonic() - start
                    with lock:
                        totals = table.per_agent()
                    summary = ", ".join(
                        f"{agent}: {t['bandwidth_bps'] / 1e3:.1f} kB/s, {int(t['dropped'])} dropped"
                        for agent, t in sorted(totals.items())
                    )
                    total = f"/{duration_s:.0f}" if duration_s else ""
                    print(f"[demo {elapsed:5.0f}{total} s] {summary or 'waiting for statistics'}", file=output,
                          flush=True)  # fmt: skip
            except KeyboardInterrupt:
                print("[demo] stopping", file=output, flush=True)
            supervisor.stop()
            supervisor_thread.join(10)
            if station is not None:
                station.stop()
            elapsed = time.monotonic() - start
    with lock:
        rows = table.rows()
    result = DemoResult(out_dir, elapsed, rows, history)
    write_results(result)
    return result


def write_results(result: DemoResult) -> None:
    """statistics.json, report.md and bandwidth.png in the output folder."""
    out = result.out_dir
    (out / "statistics.json").write_text(json.dumps([r.as_dict() for r in result.rows], indent=1))
    lines = [
        "# fleetslam demo report",
        "",
        f"Run of {result.duration_s:.0f} s. Latest statistics window per topic and subscriber:",
        "",
        "| agent | topic | publisher → subscriber | kB/s | Hz | delivered | dropped | age ms (mean ± std) |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in result.rows:
        lines.append(
            f"| {r.agent} | {r.topic} | {r.node_pub} → {r.node_sub} | {r.bandwidth_bps / 1e3:.1f} | {r.rate_hz:.1f} "
            f"| {r.delivered} | {r.dropped} | {r.age_mean_ms:.2f} ± {r.age_std_ms:.2f} |"
        )
    lines += ["", "## Per agent", "", "| agent | kB/s | delivered | dropped |", "|---|---:|---:|---:|"]
    for agent, t in sorted(result.per_agent().items()):
        lines.append(f"| {agent} | {t['bandwidth_bps'] / 1e3:.1f} | {int(t['delivered'])} | {int(t['dropped'])} |")
    plot = _plot_bandwidth(result)
    if plot is not None:
        lines += ["", f"![bandwidth over time]({plot.name})"]
    (out / "report.md").write_text("\n".join(lines) + "\n")


def _plot_bandwidth(result: DemoResult) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed: no bandwidth plot (pip install 'fleetslam[eval]')")
        return None
    if not result.history:
        return None
    t0 = min(h["t"] for h in result.history)
    fig, ax = plt.subplots(figsize=(8, 4), dpi=110)
    series: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for h in result.history:
        series.setdefault((h["topic"], h["subscriber"]), []).append((h["t"] - t0, h["bandwidth_bps"] / 1e3))
    for (topic, subscriber), points in sorted(series.items()):
        xs, ys = zip(*points, strict=True)
        ax.plot(xs, ys, label=f"{topic} → {subscriber}", marker=".", linewidth=1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("bandwidth (kB/s)")
    ax.set_title("Bandwidth per topic (from /statistics)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = result.out_dir / "bandwidth.png"
    fig.savefig(path)
    plt.close(fig)
    return path
