"""Issue 14: a 30 s link cut between two SLAM agents on two hosts (network namespaces, as the multi-host test), with
no keyframe lost. Each agent (``collab_link_cut_agent.py``, real SLAM on rendered frames) drives back and forth
along a route that overlaps the other's; once r2d2 is placed in the fleet frame, r2d2's cable is pulled for 30 s
and both keep mapping alone. After the link is back, each one's mirror of the other's graph holds every keyframe
the other made, the summaries of those made during the cut arrived by catch-up (they were lost on the stream), and
r2d2 is still placed where the truth says."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam.geometry import invert, rotation_angle
from fleetslam.launch.netns import VirtualNetwork, netns_available

pytestmark = [pytest.mark.netns, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]
CUT_S = 30.0
AGENTS = {"c3po": "r2d2", "r2d2": "c3po"}


class Agent:
    """An agent process and what it printed (its stdout is read by a thread: it flows while the link is down)."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.process = process
        self.statuses: list[dict[str, Any]] = []
        self.reports: list[dict[str, Any]] = []
        self.ready = threading.Event()
        self.other: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            if not line.startswith("{"):
                self.other.append(line)
                continue
            record = json.loads(line)
            if "ready" in record:
                self.ready.set()
            elif "status" in record:
                self.statuses.append(record)
            elif "report" in record:
                self.reports.append(record)

    @property
    def status(self) -> dict[str, Any]:
        return self.statuses[-1] if self.statuses else {}

    def send(self, command: str) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()


def _wait(predicate: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


def test_a_30s_link_cut_loses_no_keyframe_and_the_summaries_come_by_catch_up() -> None:
    ok, why = netns_available()
    if not ok:
        pytest.skip(f"cannot create network namespaces here: {why}")
    pythonpath = {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), str(ROOT),
                                                               os.environ.get("PYTHONPATH")]))}  # fmt: skip
    started = time.monotonic()
    with VirtualNetwork(list(AGENTS), prefix=f"fc{os.getpid() % 100000}", subnet="10.79.0.0/24") as net:
        procs: list[subprocess.Popen[str]] = []
        agents: dict[str, Agent] = {}
        try:
            router = [sys.executable, "-m", "fleetslam.cli.main", "router", "--listen", f"tcp/{net.host.address}:7447"]
            procs.append(net.popen("host", router, env=pythonpath, stdout=subprocess.DEVNULL))
            time.sleep(0.8)
            for agent, peer in AGENTS.items():
                process = net.popen(agent, [sys.executable, "-m", "tests.integration.collab_link_cut_agent", agent,
                                            peer], env=pythonpath, cwd=str(ROOT), stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE)  # fmt: skip
                procs.append(process)
                agents[agent] = Agent(process)
            assert all(a.ready.wait(120.0) for a in agents.values()), {n: a.other[-5:] for n, a in agents.items()}
            # Mapping together: each mirrors the other's graph, and r2d2 is placed in the fleet frame (c3po's).
            assert _wait(lambda: agents["r2d2"].status.get("placed", False)
                         and all(a.status.get("synced") and a.status.get("mirror", 0) > 3 for a in agents.values()),
                         60.0), {n: a.status for n, a in agents.items()}  # fmt: skip

            before = {name: a.status["keyframes"] for name, a in agents.items()}
            cut_at = time.time()
            net.set_link("r2d2", up=False)
            time.sleep(CUT_S)
            restored_at = time.time()
            net.set_link("r2d2", up=True)
            during = {name: a.status["keyframes"] - before[name] for name, a in agents.items()}
            made_by = {name: a.status["keyframes"] for name, a in agents.items()}

            def caught_up() -> bool:
                return all(
                    a.status["synced"] and a.status["missing"] == 0 and a.status["mirror"] >= made_by[AGENTS[n]]
                    for n, a in agents.items()
                )

            assert _wait(caught_up, 60.0), {n: a.status for n, a in agents.items()}
            catch_up_s = time.time() - restored_at
            for a in agents.values():
                a.send("park")  # stand still: no new keyframes, and the last ones reach the graph

            def settled() -> bool:
                return all(
                    a.status["sent"] == a.status["keyframes"] and a.status["missing"] == 0
                    and agents[AGENTS[n]].status["mirror"] == a.status["sent"]
                    for n, a in agents.items()
                )  # fmt: skip

            # Settled for 2 s in a row: a keyframe the parked camera still made in its first moments (on a loaded
            # machine its last frames arrive late) would otherwise be reported by one side before the other has it.
            stable: dict[str, Any] = {"counts": None, "since": 0.0}

            def settled_for_2s() -> bool:
                counts = {n: (a.status["keyframes"], a.status["mirror"]) for n, a in agents.items()}
                if not settled() or counts != stable["counts"]:
                    stable.update(counts=counts, since=time.time())
                    return False
                return time.time() - stable["since"] >= 2.0

            time.sleep(1.0)
            assert _wait(settled_for_2s, 30.0), {n: a.status for n, a in agents.items()}
            for a in agents.values():
                a.send("report")
            assert _wait(lambda: all(a.reports for a in agents.values()), 20.0)
            reports = {name: a.reports[-1] for name, a in agents.items()}
            statuses = {name: list(a.statuses) for name, a in agents.items()}
        finally:
            for a in agents.values():
                if a.process.poll() is None:
                    a.send("stop")
            for proc in procs:
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.terminate()
                    try:
                        proc.wait(timeout=5)
                    except subprocess.TimeoutExpired:
                        proc.kill()

    for name, peer in AGENTS.items():
        mine, theirs = reports[name], reports[peer]
        made = {int(k): t for k, t in mine["made"].items()}
        # Both kept mapping alone during the cut.
        assert during[name] >= 5, (name, during)
        # Every keyframe this agent made (and put in its graph) is in the peer's mirror, with its summary.
        assert set(mine["sent"]) == set(made), (name, sorted(set(made) ^ set(mine["sent"])))
        assert set(mine["sent"]) <= set(theirs["mirror"]), (name, sorted(set(mine["sent"]) - set(theirs["mirror"])))
        assert set(mine["sent"]) <= set(theirs["received"]), (name, sorted(set(mine["sent"]) - set(theirs["received"])))
        assert not theirs["unavailable"]
        # The summaries of the keyframes made during the cut were lost on the stream; they came by catch-up.
        in_cut = {k for k, t in made.items() if cut_at + 1.0 < t < restored_at}  # seen up to 0.5 s after it was made
        assert len(in_cut) >= 5 and in_cut <= set(theirs["caught_up"]), (
            name,
            sorted(in_cut - set(theirs["caught_up"])),
        )
        assert mine["counts"]["bad_peer_messages"] == 0
    # The cut did not break r2d2's placement: still where the truth puts c3po's map frame.
    expected = invert(np.asarray(reports["c3po"]["world_from_map"])) @ np.asarray(reports["r2d2"]["world_from_map"])
    placed = reports["r2d2"]["fleet_transform"]
    assert placed is not None
    error = invert(expected) @ np.asarray(placed)
    assert np.linalg.norm(error[:3, 3]) < 0.05 and np.degrees(rotation_angle(error)) < 1.0, error
    for name, report in reports.items():
        peer = AGENTS[name]
        resynced = next(r["t"] for r in statuses[name]
                        if r["t"] > restored_at and r["synced"] and r["mirror"] >= made_by[peer])  # fmt: skip
        timeline = [(round(r["t"] - restored_at, 1), r["caught_up"], r["missing"], r["queued"], r["catch_up_failures"])
                    for r in statuses[name][::2] if r["t"] > restored_at]  # fmt: skip
        print(f"{name}: (s after the link came back, caught up, missing, queued, failed requests) {timeline}")
        print(f"{name}: mirror of {peer} whole again {resynced - restored_at:.1f} s after the link came back")
        print(f"{name}: {during[name]} keyframes during the {CUT_S:.0f} s cut, {len(report['caught_up'])} summaries "
              f"of {AGENTS[name]} caught up, store {report['store']} summaries = {report['store_bytes'] / 1e3:.0f} kB"
              f", catch-up complete {catch_up_s:.1f} s after the link came back; "
              f"status lines {len(statuses[name])}; test {time.monotonic() - started:.0f} s")  # fmt: skip
    print(f"placement error {np.linalg.norm(error[:3, 3]) * 100:.1f} cm, {np.degrees(rotation_angle(error)):.2f} deg")
