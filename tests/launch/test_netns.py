"""The seed's setup on one machine: a router host and two agents in network namespaces joined by a bridge."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleetslam.launch.netns import VirtualNetwork, netns_available

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
pytestmark = pytest.mark.netns


def _fleetslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleetslam.cli.main", *args]


def test_two_agents_viewer_stats_and_link_outage() -> None:
    ok, why = netns_available()
    if not ok:
        pytest.skip(f"cannot create network namespaces here: {why}")
    with VirtualNetwork(["c3po", "r2d2"], prefix=f"fs{os.getpid() % 100000}", subnet="10.77.0.0/24") as net:
        procs: list[subprocess.Popen[str]] = []
        try:
            procs.append(net.popen("host", _fleetslam("router", "--listen", f"tcp/{net.host.address}:7447")))
            time.sleep(0.8)
            for agent, peer in (("c3po", "r2d2"), ("r2d2", "c3po")):
                procs.append(
                    net.popen(
                        agent,
                        [sys.executable, str(EXAMPLES / "graph_agent.py"), "--peers", peer, "--rate", "10"],
                        stdout=subprocess.PIPE,
                        stderr=subprocess.STDOUT,
                    )
                )
            # The viewer on the host sees both agents' graphs.
            for agent in ("c3po", "r2d2"):
                echo = net.run(
                    "host", _fleetslam("topic", "echo", f"/{agent}/graph", "--count", "1", "--timeout", "15")
                )
                assert echo.returncode == 0, echo.stdout + echo.stderr
                assert f"agent: {agent}" in echo.stdout
            stats = subprocess.Popen(
                net.command("host", _fleetslam("stats", "--json", "--duration", "16")),
                env={**os.environ, **net.environment("host")},
                text=True,
                stdout=subprocess.PIPE,
            )
            procs.append(stats)
            time.sleep(4.0)
            down_at = time.time_ns()
            net.set_link("r2d2", up=False)
            time.sleep(4.0)
            net.set_link("r2d2", up=True)
            up_at = time.time_ns()
            out, _ = stats.communicate(timeout=30)
            rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
        finally:
            for proc in procs:
                proc.terminate()
            for proc in procs:
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    proc.kill()
    agents = {r["agent"] for r in rows}
    assert {"c3po", "r2d2"} <= agents, agents
    r2d2 = [r for r in rows if r["topic"] == "/r2d2/graph" and r["node_sub"] == "/c3po/slam"]
    before = [r for r in r2d2 if r["stamp_ns"] < down_at]
    after = [r for r in r2d2 if r["stamp_ns"] > up_at + 2e9]
    assert before and all(r["delivered"] > 0 for r in before)
    assert after and after[-1]["delivered"] >= 5, "traffic did not resume after the link came back"
    during = [r for r in r2d2 if down_at + 1.5e9 < r["stamp_ns"] < up_at]
    assert sum(r["delivered"] for r in during) == 0, "messages crossed a link that was down"
    # The gap is visible after recovery: lost messages, or a period as long as the outage.
    recovered = [r for r in r2d2 if r["stamp_ns"] > up_at]
    assert any(r["dropped"] > 0 or r["period_max_ms"] > 2500 for r in recovered), recovered[:3]  # a 4 s outage
    # c3po's graph kept flowing to r2d2 before and after.
    assert any(r["topic"] == "/c3po/graph" and r["node_sub"] == "/r2d2/slam" for r in rows)
