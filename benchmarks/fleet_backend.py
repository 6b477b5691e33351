"""The fleet back-end at scale (issue 14, item 7): 32 agents' graph updates replayed at 1 keyframe/s each into one
fleet back-end node (``fleetslam fleet backend``, its own process) over a real Zenoh router, for at least 60 s.

What is real and what is replicated:

- **Recorded once, real**: two SLAM agents (``c3po``, ``r2d2``, the defaults, wheel prior) run offline side by
  side on the simulator exports of ``benchmarks/collaborative.py`` (the same part of the plant entered from opposite
  corners, no known start poses). Each one's keyframe graph goes out as it would on ``graph_updates``: deltas from
  a :class:`~fleetslam.fusion.graph_exchange.GraphDeltaWriter` after every keyframe, with the agent's odometry and
  loop constraints and the inter-agent closures its :class:`~fleetslam.fusion.collaboration.InterAgentLinker`
  verified against the other's keyframe summaries (``INTER_AGENT``, every verified match, as the SLAM node
  publishes them: right and wrong ones). They are written as ``fleetslam_msgs/KeyframeGraph`` CDR into a rosbag2
  folder (MCAP) under ``FLEETSLAM_BENCH_CACHE/fleet_backend``.
- **Replicated**: 16 copies of that pair make 32 agents (``c3po_00``, ``r2d2_00``, ... ``r2d2_15``). Each copy has
  its own epochs, its closures renamed and their ``to_epoch`` remapped within the copy, and its map frame moved by
  a random rigid transform (its poses are the recorded ones in another frame). A copy is the same run as the
  others, so copy k's keyframe i is where copy k-1's keyframe i is: every 10th keyframe (every 3rd of the first
  12) of each of its two agents carries a closure to the previous copy's same keyframe with the identity as
  relative pose (true by construction; it links the copies into one fleet, without it only copy 0 would be placed
  and solved). The r2d2 copies are placed once the recorded closures between c3po and r2d2 are believed (~140 s
  in, since the closures' precision rule): the replay covers the whole recording (206 updates per agent), and the
  target counts only when every agent was placed (a run that ends first measured half the fleet).
- **Paced**: each agent's recorded updates go out one per second (staggered by 1/32 s between agents), so that
  each agent adds ~1 keyframe/s (the SLAM node publishes its graph at most once a second); an agent's ``graph/full``
  is served from what was replayed of it, should the back-end miss an update.

Figures: lag from a keyframe's update being published to the keyframe appearing in that agent's published
``fleet_path`` (median, p95, max; target < 1 s; counted for keyframes published once their agent was placed:
before, they wait for closures, not for the back-end), keyframes per second in, the back-end process's CPU (% of
one core) and peak RSS, its solve time per cycle (from ``/fleet/backend/diagnostics``: wall and CPU time,
median, p95, max; how many ran GNC), agents placed, closures kept, rejected and pending (waiting for GNC's verdict).
The machine is shared (2 cores, other work running), as the JSON says (``load_average``): wall times include
waiting for a core, CPU times do not.
The replayer and the lag measurement run in this process, niced like the back-end. Prints one JSON line;
progress on stderr; ``fleet_backend.png``: lag and solve time over the run.

With ``--offline``, the same replay goes straight into the back-end's ``FleetGraph`` in this process, the node's
pacing simulated on each solve's CPU time (see :func:`run_offline`): the lag the solves add on an idle core, for a
machine too busy for the live figures to say it.

Usage: python benchmarks/fleet_backend.py [--copies 16] [--duration S] [--out results/benchmarks] [--offline]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.fusion.fleet_graph import FleetSolution
from fleetslam.fusion.fleet_graph_node import FleetGraphConfig, closure_update, fleet_graph
from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphMirror, GraphUpdate, graph_message
from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.middleware import Context, Node, Router
from fleetslam.middleware.recording import BagWriter, read_bag
from fleetslam.msg.conversions import pose_matrix, pose_msg, pose_msgs
from fleetslam.msg.typesys import deserialize, get_type, ns_from_stamp, serialize
from fleetslam.slam.peer_recognition import closure_information

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collaborative import AGENTS, cache_dir, export, make_agent

GRAPH_TYPE = "fleetslam_msgs/msg/KeyframeGraph"
TARGET_LAG_S = 1.0
LINK_EVERY = 10
"""Every this many keyframes, a copy's agent is linked to the previous copy's same keyframe ..."""
LINK_FIRST = 12
"""... and every 3rd of its first ones (so that the copies are placed from the start)."""


# -- recording (once, cached) ------------------------------------------------------------------------------------
def _constraint(**fields: Any) -> Any:
    return get_type("fleetslam_msgs/msg/GraphConstraint")(**fields)


def record(scene: str, route: str, size: tuple[int, int], hz: float) -> Path:
    """The two real agents' graph updates, recorded once (see the module docstring)."""
    # v2: the closures carry their covariance (as the SLAM node sends them since the precision rule).
    out = cache_dir() / "fleet_backend" / f"{scene}_{route}_{size[0]}x{size[1]}_{hz:g}hz_v2"
    if (out / "metadata.yaml").is_file():
        return out
    import cv2

    cv2.setNumThreads(1)
    plans = AGENTS[:2]  # the two robots of the demo's shared patrol
    if any(plan.route != route for plan in plans):
        raise SystemExit(f"--route {route}: the recorded pair drives {plans[0].route} (benchmarks/collaborative.py)")
    agents = [make_agent(plan, export(scene, plan, size, hz), collaborate=True) for plan in plans]
    linkers = {agent.name: agent.linker for agent in agents if agent.linker is not None}
    writers = {a.name: GraphDeltaWriter[Any]() for a in agents}
    constraints: dict[str, list[Any]] = {a.name: [] for a in agents}
    taken = dict.fromkeys(writers, 0)
    stamps: dict[str, dict[int, float]] = {a.name: {} for a in agents}
    iterators = [iter(a.source.frames(1)) for a in agents]
    done = [False, False]
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    frames, started = 0, time.perf_counter()
    with BagWriter(tmp) as bag:
        while not all(done):
            for index, agent in enumerate(agents):
                if done[index]:
                    continue
                frame = next(iterators[index], None)
                if frame is None:
                    done[index] = True
                    continue
                frames += 1
                other = agents[1 - index]
                step = agent.pipeline.step(frame)
                matches = []
                linker = linkers[agent.name]
                if linker.queue and agent.pipeline.loop_closure:
                    if agent.recognizer is None:
                        agent.recognizer = agent.pipeline.peer_recognizer()
                    matches = linker.step(agent.recognizer, agent.pipeline.keyframe_poses())
                epoch_of_other = writers[other.name].epoch
                constraints[agent.name] += [
                    _constraint(from_id=m.own_id, to_id=m.peer_id, from_agent=agent.name, to_agent=m.peer_agent,
                                kind=2, relative=pose_msg(m.relative), information=closure_information(m),
                                to_epoch=epoch_of_other)
                    for m in matches
                ]  # fmt: skip
                if step.keyframe_id is None:
                    continue
                from fleetslam.fusion.keyframe_summary import summarize

                poses = agent.pipeline.keyframe_poses()
                stamps[agent.name][step.keyframe_id] = frame.stamp
                result = step.odometry
                linkers[other.name].queue_summary(
                    summarize(agent.name, step.keyframe_id, round(frame.stamp * 1e9), poses[step.keyframe_id],
                              agent.pipeline.intrinsics, result.keypoints, result.points3d,
                              np.asarray(result.descriptors), epoch=writers[agent.name].epoch)
                )  # fmt: skip
                own = agent.pipeline.constraints()
                if len(own) < taken[agent.name]:  # a loop retracted: the list is rebuilt (a full graph goes out)
                    constraints[agent.name], taken[agent.name] = [], 0
                constraints[agent.name] += [
                    _constraint(from_id=c.a, to_id=c.b, from_agent=agent.name, to_agent=agent.name,
                                kind=1 if c.kind == "loop" else 0, relative=pose_msg(c.transform),
                                information=np.asarray(c.information, np.float64).reshape(36), to_epoch=0)
                    for c in own[taken[agent.name]:]
                ]  # fmt: skip
                taken[agent.name] = len(own)
                update = writers[agent.name].update(poses, stamps[agent.name], constraints[agent.name])
                if update is None:
                    continue
                linkers[other.name].apply_graph(agent.name, update)
                msg = graph_message(agent.name, update, stamp_ns=round(frame.stamp * 1e9), optimized=step.loop_closed)
                bag.write(topics.GRAPH_UPDATES.of(agent.name), GRAPH_TYPE, round(frame.stamp * 1e9),
                          serialize(msg, GRAPH_TYPE))  # fmt: skip
            if frames % 200 < 2:
                print(f"  recording: {frames} frames, {time.perf_counter() - started:.0f} s", file=sys.stderr,
                      flush=True)  # fmt: skip
    tmp.rename(out)
    return out


# -- replication ---------------------------------------------------------------------------------------------------
@dataclass
class Replica:
    """One replayed agent: its messages (CDR, in order), what they introduce, and what was replayed of it."""

    name: str
    epoch: int
    messages: list[bytes] = field(default_factory=list)
    new_stamps: list[list[int]] = field(default_factory=list)
    """Per message, the stamps (µs) of the keyframes it adds."""
    mirror: GraphMirror[Any] = field(default_factory=GraphMirror)
    lock: threading.Lock = field(default_factory=threading.Lock)


def replicate(recording: Path, copies: int, seed: int = 0) -> dict[str, Replica]:
    """The recorded pair as ``copies`` pairs (see the module docstring), messages serialised ahead of the run."""
    rng = np.random.default_rng(seed)
    recorded: dict[str, list[Any]] = {}
    for message in read_bag(recording):
        msg = deserialize(message.data, GRAPH_TYPE)
        recorded.setdefault(str(msg.agent), []).append(msg)
    names = sorted(recorded)
    replicas = {f"{name}_{k:02d}": Replica(f"{name}_{k:02d}", int(rng.integers(1, 2**62)))
                for k in range(copies) for name in names}  # fmt: skip
    for k in range(copies):
        frame = pose_from_xyz_rpy(*rng.uniform(-20.0, 20.0, 3) * [1.0, 0.0, 1.0],
                                  0.0, float(rng.uniform(-np.pi, np.pi)), 0.0)  # fmt: skip
        rename = {name: f"{name}_{k:02d}" for name in names}
        for name in names:
            replica = replicas[rename[name]]
            previous = replicas.get(f"{name}_{k - 1:02d}") if k else None
            seen: set[int] = set()
            for msg in recorded[name]:
                ids = [int(i) for i in msg.keyframe_ids]
                new = [i for i in ids if i not in seen]
                seen.update(ids)
                poses = pose_msgs([frame @ pose_matrix(p) for p in msg.poses])
                constraints = []
                for c in msg.constraints:
                    to_agent = rename.get(str(c.to_agent), str(c.to_agent))
                    to_epoch = replicas[to_agent].epoch if int(c.kind) == 2 else 0
                    constraints.append(_constraint(
                        from_id=int(c.from_id), to_id=int(c.to_id), from_agent=replica.name, to_agent=to_agent,
                        kind=int(c.kind), relative=c.relative, information=c.information, to_epoch=to_epoch,
                    ))  # fmt: skip
                if previous is not None:
                    constraints += [
                        _constraint(from_id=i, to_id=i, from_agent=replica.name, to_agent=previous.name, kind=2,
                                    relative=pose_msg(np.eye(4)), information=np.zeros(36),  # closure_sigma
                                    to_epoch=previous.epoch)
                        for i in new if i % LINK_EVERY == 0 or (i < LINK_FIRST and i % 3 == 0)
                    ]  # fmt: skip
                copy = get_type(GRAPH_TYPE)(
                    header=msg.header, agent=replica.name, keyframe_ids=msg.keyframe_ids, stamps=msg.stamps,
                    poses=poses, constraints=constraints, optimized=msg.optimized, sequence=msg.sequence,
                    full=msg.full, epoch=replica.epoch,
                )  # fmt: skip
                replica.messages.append(serialize(copy, GRAPH_TYPE))
                stamp_of = {int(i): ns_from_stamp(s) for i, s in zip(msg.keyframe_ids, msg.stamps, strict=True)}
                replica.new_stamps.append([stamp_of[i] // 1000 for i in new])
    return replicas


# -- the run -------------------------------------------------------------------------------------------------------
def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def run(args: argparse.Namespace) -> dict[str, Any]:
    size = tuple(int(v) for v in args.resolution.split("x"))
    recording = record(args.scene, args.route, size, args.rate)  # type: ignore[arg-type]
    replicas = replicate(recording, args.copies)
    updates_per_agent = min(min(len(r.messages) for r in replicas.values()), round(args.duration))
    print(f"  {len(replicas)} agents, {updates_per_agent} updates each", file=sys.stderr, flush=True)
    endpoint = f"tcp/127.0.0.1:{args.port or _free_port()}"
    published: dict[tuple[str, int], float] = {}
    """(agent, keyframe stamp µs) -> wall time its update was published."""
    lags: list[tuple[float, float]] = []
    """(seconds since the start, lag) per keyframe seen in a path."""
    seen: set[tuple[str, int]] = set()
    placed: set[str] = set()
    """The agents of the latest ``/fleet/placements``."""
    timed: set[tuple[str, int]] = set()
    """Keyframes published while their agent was placed: the others wait for evidence (closures), not for the
    back-end, and are not counted in the lag."""
    in_paths: set[str] = set()
    solves: list[dict[str, str]] = []
    lock = threading.Lock()
    env = dict(os.environ, FLEETSLAM_ROUTER=endpoint)
    with Router([endpoint]), Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as ctx:
        backend = subprocess.Popen(
            ["nice", "-n", "10", sys.executable, "-m", "fleetslam.cli.main", "fleet", "backend",
             *(a for setting in args.set for a in ("--set", setting))],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            node = Node("fleet_replay", context=ctx)
            updates = topics.GRAPH_UPDATES
            pubs = {name: node.create_publisher(updates.type, updates.of(name), updates.qos()) for name in replicas}

            def full_graph(replica: Replica, request: Any) -> Any:
                with replica.lock:
                    m = replica.mirror
                    full = GraphUpdate(max(m.sequence, 1), True, dict(m.poses), dict(m.stamps), list(m.constraints),
                                       replica.epoch)  # fmt: skip
                return get_type("fleetslam_msgs/srv/GetGraph_Response")(graph=graph_message(replica.name, full))

            for replica in replicas.values():
                node.create_service("fleetslam_msgs/srv/GetGraph", f"/{replica.name}/graph/full",
                                    lambda request, r=replica: full_graph(r, request))  # fmt: skip
            t0 = time.monotonic()

            def on_path(agent: str, msg: Any) -> None:
                now = time.monotonic()
                with lock:
                    in_paths.add(agent)
                    for pose in msg.poses:
                        key = (agent, ns_from_stamp(pose.header.stamp) // 1000)
                        if key not in seen and key in published:
                            seen.add(key)
                            if key in timed:  # its agent was placed when it went out: waiting for the back-end only
                                lags.append((now - t0, now - published[key]))

            def on_placements(msg: Any) -> None:
                agents = {str(t.child_frame_id).split("/")[0] for t in msg.transforms}
                with lock:
                    placed.clear()
                    placed.update(agents)

            def on_diagnostics(msg: Any) -> None:
                for status in msg.status:
                    if status.name == "fleet_backend":
                        solves.append({kv.key: kv.value for kv in status.values} | {"t": str(time.monotonic() - t0)})

            path = topics.FLEET_PATH
            for name in replicas:
                node.create_subscription(path.type, path.of(name), lambda m, a=name: on_path(a, m), path.qos(depth=2))
            placements = topics.FLEET_PLACEMENTS
            node.create_subscription(placements.type, placements.name, on_placements, placements.qos(depth=5))
            diagnostics = topics.FLEET_BACKEND_DIAGNOSTICS
            node.create_subscription(diagnostics.type, diagnostics.name, on_diagnostics, diagnostics.qos(depth=50))
            time.sleep(3.0)  # the back-end process starts (imports, router session)
            cpu0, wall0 = _proc_cpu_s(backend.pid), time.monotonic()
            rss_peak = 0.0
            names = sorted(replicas)
            t0 = time.monotonic()
            schedule = sorted(
                (step + i / len(names), name, step) for i, name in enumerate(names) for step in range(updates_per_agent)
            )  # fmt: skip
            last_report = 0.0
            for at, name, step in schedule:
                delay = t0 + at - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                replica = replicas[name]
                data = replica.messages[step]
                with replica.lock:
                    replica.mirror.apply(_update_of(data))
                now = time.monotonic()
                with lock:
                    for stamp in replica.new_stamps[step]:
                        published[(name, stamp)] = now
                        if name in placed:
                            timed.add((name, stamp))
                pubs[name].publish_raw(data)
                if now - last_report >= 10.0:
                    last_report = now
                    rss_peak = max(rss_peak, _proc_rss_mb(backend.pid))
                    with lock:
                        recent = [lag for t, lag in lags if t > now - t0 - 10.0]
                    p50 = np.median(recent) if recent else float("nan")
                    print(f"  {now - t0:.0f} s: {len(published)} keyframes out, {len(seen)} in paths, lag p50 "
                          f"{p50:.2f} s", file=sys.stderr, flush=True)  # fmt: skip
                if step % 5 == 0:
                    rss_peak = max(rss_peak, _proc_rss_mb(backend.pid))
            end_of_input = time.monotonic()
            deadline = end_of_input + 10.0
            while time.monotonic() < deadline and len(seen) < len(published):
                time.sleep(0.1)
            cpu = _proc_cpu_s(backend.pid) - cpu0
            busy_s = time.monotonic() - wall0
            rss_peak = max(rss_peak, _proc_rss_mb(backend.pid))
            node.destroy()
        finally:
            backend.terminate()
            try:
                _, err = backend.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                backend.kill()
                _, err = backend.communicate()
    lag_values = np.array([lag for _, lag in lags]) if lags else np.array([np.nan])
    solve_ms = np.array([float(s["solve_ms"]) for s in solves]) if solves else np.array([np.nan])
    solve_cpu_ms = np.array([float(s["solve_cpu_ms"]) for s in solves]) if solves else np.array([np.nan])
    robust = [s.get("robust") == "True" for s in solves]
    last = solves[-1] if solves else {}
    duration = end_of_input - t0
    record_: dict[str, Any] = {
        "benchmark": "fleet_backend", "agents": len(replicas), "copies": args.copies,
        "recorded_from": f"{args.scene} {args.route} {args.resolution} {args.rate:g} Hz, 2 real SLAM agents",
        "duration_s": round(duration, 1), "keyframes_published": len(published),
        "keyframes_per_s": round(len(published) / max(duration, 1e-9), 1),
        "keyframes_in_paths": len(seen), "keyframes_never_seen": len(published) - len(seen),
        "keyframes_timed": len(lags), "agents_in_paths": len(in_paths),
        "lag_s_median": round(float(np.median(lag_values)), 3),
        "lag_s_p95": round(float(np.percentile(lag_values, 95)), 3),
        "lag_s_max": round(float(np.max(lag_values)), 3),
        "backend_cpu_percent_of_one_core": round(100.0 * cpu / max(busy_s, 1e-9), 1),
        "backend_rss_mb_peak": round(rss_peak, 1),
        "solves": len(solves), "solve_ms_median": round(float(np.median(solve_ms)), 1),
        "solve_ms_p95": round(float(np.percentile(solve_ms, 95)), 1), "solve_ms_max": round(float(np.max(solve_ms)), 1),
        "solve_cpu_ms_median": round(float(np.median(solve_cpu_ms)), 1),
        "solve_cpu_ms_p95": round(float(np.percentile(solve_cpu_ms, 95)), 1),
        "solve_cpu_ms_max": round(float(np.max(solve_cpu_ms)), 1),
        "gnc_solves": int(sum(robust)),
        "agents_placed": int(last.get("agents_placed", 0)), "variables": int(last.get("variables", 0)),
        "closures_kept": int(last.get("closures_kept", 0)), "closures_rejected": int(last.get("closures_rejected", 0)),
        "closures_pending": int(last.get("closures_pending", 0)),
        "graph_requests": int(last.get("graph_requests", 0)),
        "load_average": [round(v, 2) for v in os.getloadavg()], "cores": os.cpu_count(),
        "machine": "shared: other work running, this benchmark and the back-end niced (nice 10)",
    }  # fmt: skip
    record_["target_lag_s"] = TARGET_LAG_S
    record_["target_met"] = bool(
        record_["lag_s_p95"] < TARGET_LAG_S and record_["lag_s_max"] < TARGET_LAG_S
        and record_["keyframes_never_seen"] == 0 and duration >= args.min_duration
        and record_["agents_placed"] == len(replicas)
    )  # fmt: skip
    if backend.returncode not in (0, -15) and err:
        print(err[-2000:], file=sys.stderr)
    plot(lags, solves, Path(args.out) / "fleet_backend.png", len(replicas))
    return record_


def run_offline(args: argparse.Namespace) -> dict[str, Any]:
    """``--offline``: the same replay straight into the back-end's :class:`FleetGraph` in this process (no router, no
    messages, no paths published), the node's worker simulated on each solve's CPU time: a solve starts once
    ``1 / rate`` and ``CPU time / max_load`` have passed since the previous one started (at the earliest when an
    update came), and ends its CPU time later; a keyframe's lag runs from its update to the end of the first solve
    that places it (counted as in the live run). What the solves add to the lag on an idle core, whatever else the
    machine runs (CPU time of a busy machine's core is still a little longer than an idle one's)."""
    size = tuple(int(v) for v in args.resolution.split("x"))
    recording = record(args.scene, args.route, size, args.rate)  # type: ignore[arg-type]
    replicas = replicate(recording, args.copies)
    updates_per_agent = min(min(len(r.messages) for r in replicas.values()), round(args.duration))
    names = sorted(replicas)
    print(f"  {len(names)} agents, {updates_per_agent} updates each, offline", file=sys.stderr, flush=True)
    events = sorted(
        (step + i / len(names), name, step) for i, name in enumerate(names) for step in range(updates_per_agent)
    )  # fmt: skip
    updates = [(at, name, closure_update(name, deserialize(replicas[name].messages[step], GRAPH_TYPE)),
                replicas[name].new_stamps[step]) for at, name, step in events]  # fmt: skip
    config = FleetGraphConfig()
    graph = fleet_graph(config)
    now, k, reported = 0.0, 0, 0.0
    placed: set[str] = set()
    waiting: dict[tuple[str, int], float] = {}
    """(agent, keyframe stamp ms) -> time its update came, for keyframes of placed agents."""
    lags: list[tuple[float, float]] = []
    solves: list[dict[str, str]] = []
    last: FleetSolution | None = None
    all_placed: float | None = None
    pending_since: dict[Any, float] = {}
    verdicts: dict[Any, float] = {}
    """Closure -> how long it waited for GNC's verdict (those that waited for a later solve)."""
    started = time.perf_counter()
    while k < len(updates) or graph.changed:
        while k < len(updates) and updates[k][0] <= now:
            at, name, update, stamps = updates[k]
            k += 1
            graph.apply(name, update)
            if name in placed:
                waiting.update({(name, round(stamp / 1000)): at for stamp in stamps})
        if not graph.changed:
            now = updates[k][0]
            continue
        solution = graph.solve()
        assert solution is not None
        last, done = solution, now + solution.cpu_seconds
        placed = set(solution.placements)
        if len(placed) == len(names) and all_placed is None:
            all_placed = done
        for c in solution.pending:
            pending_since.setdefault(c.key, now)
        for c in solution.kept + solution.rejected:
            if c.key in pending_since and c.key not in verdicts:
                verdicts[c.key] = done - pending_since[c.key]
        for name, placement in solution.placements.items():
            for stamp in placement.stamps.values():
                at_ = waiting.pop((name, round(stamp * 1e3)), None)
                if at_ is not None:
                    lags.append((now, done - at_))
        solves.append({"t": str(now), "solve_ms": str(solution.seconds * 1e3),
                       "solve_cpu_ms": str(solution.cpu_seconds * 1e3), "robust": str(solution.robust)})  # fmt: skip
        now += max(1.0 / config.rate, solution.cpu_seconds / config.max_load)
        if now - reported >= 10.0:
            reported = now
            print(f"  {now:.0f} s simulated, {len(placed)} agents placed", file=sys.stderr, flush=True)
    lag_values = np.array([lag for _, lag in lags]) if lags else np.array([np.nan])
    solve_cpu_ms = np.array([float(s["solve_cpu_ms"]) for s in solves]) if solves else np.array([np.nan])
    record_: dict[str, Any] = {
        "benchmark": "fleet_backend", "mode": "offline (FleetGraph in process, pacing simulated on CPU time)",
        "agents": len(replicas), "copies": args.copies, "duration_s": updates_per_agent,
        "keyframes_timed": len(lags), "keyframes_never_placed": len(waiting),
        "lag_s_median": round(float(np.median(lag_values)), 3),
        "lag_s_p95": round(float(np.percentile(lag_values, 95)), 3),
        "lag_s_max": round(float(np.max(lag_values)), 3),
        "solves": len(solves), "gnc_solves": sum(s["robust"] == "True" for s in solves),
        "solve_cpu_ms_median": round(float(np.median(solve_cpu_ms)), 1),
        "solve_cpu_ms_p95": round(float(np.percentile(solve_cpu_ms, 95)), 1),
        "solve_cpu_ms_max": round(float(np.max(solve_cpu_ms)), 1),
        "solve_cpu_s_total": round(float(np.nansum(solve_cpu_ms)) / 1e3, 1),
        "gnc_budget": config.gnc_budget,
        "agents_placed": 0 if last is None else len(last.placements),
        "closures_kept": 0 if last is None else len(last.kept),
        "closures_rejected": 0 if last is None else len(last.rejected),
        "closures_pending": 0 if last is None else len(last.pending),
        "closures_waited": len(verdicts),
        "verdict_wait_s_p95": round(float(np.percentile(list(verdicts.values()), 95)), 2) if verdicts else 0.0,
        "verdict_wait_s_max": round(max(verdicts.values()), 2) if verdicts else 0.0,
        "all_agents_placed_at_s": None if all_placed is None else round(all_placed, 1),
        "wall_s": round(time.perf_counter() - started, 1),
        "load_average": [round(v, 2) for v in os.getloadavg()], "cores": os.cpu_count(),
    }  # fmt: skip
    record_["target_lag_s"] = TARGET_LAG_S
    record_["target_met"] = bool(
        record_["lag_s_p95"] < TARGET_LAG_S and record_["lag_s_max"] < TARGET_LAG_S
        and record_["agents_placed"] == len(replicas)
    )  # fmt: skip
    plot(lags, solves, Path(args.out) / "fleet_backend_offline.png", len(replicas))
    return record_


def _update_of(data: bytes) -> GraphUpdate[Any]:
    from fleetslam.fusion.graph_exchange import graph_update_of

    return graph_update_of(deserialize(data, GRAPH_TYPE))


def plot(lags: list[tuple[float, float]], solves: list[dict[str, str]], path: Path, agents: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    if lags:
        t, lag = zip(*lags, strict=True)
        top.plot(t, lag, ".", ms=2, alpha=0.5, label="keyframe → in its agent's fleet_path")
    top.axhline(TARGET_LAG_S, color="red", lw=1, label="target")
    top.set_ylabel("lag (s)")
    top.set_title(f"fleet back-end: {agents} agents at 1 keyframe/s each")
    top.legend(loc="upper left")
    if solves:
        t = [float(s["t"]) for s in solves]
        bottom.plot(t, [float(s["solve_ms"]) for s in solves], ".-", ms=3, lw=0.5, label="solve (wall)")
        bottom.plot(t, [float(s["solve_cpu_ms"]) for s in solves], ".", ms=3, color="tab:green", label="solve (CPU)")
        gnc = [(float(s["t"]), float(s["solve_ms"])) for s in solves if s.get("robust") == "True"]
        if gnc:
            bottom.plot(*zip(*gnc, strict=True), "x", color="tab:red", ms=4, label="with GNC (closures judged)")
        bottom.legend(loc="upper left")
    bottom.set_ylabel("solve time (ms)")
    bottom.set_xlabel("time since the replay started (s)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=16, help="copies of the recorded pair (agents = 2 × copies)")
    parser.add_argument(
        "--duration",
        type=float,
        default=1e9,
        help="replay this long (s; default and at most: the whole recording, 206 s; all its agents placed ~140 s in)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of the back-end node (live runs), e.g. rate=2.0")  # fmt: skip
    parser.add_argument("--min-duration", type=float, default=60.0, help="shortest replay that counts (s)")
    parser.add_argument("--route", default="loop_revisit")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--rate", type=float, default=10.0, help="camera rate of the recorded exports (Hz)")
    parser.add_argument("--scene", default="procedural", choices=("procedural", "photographic"))
    parser.add_argument("--port", type=int, default=0, help="the router's port (0: a free one)")
    parser.add_argument("--out", default="results/benchmarks")
    parser.add_argument("--offline", action="store_true",
                        help="replay into the back-end's FleetGraph in this process, pacing simulated on CPU time "
                             "(figures independent of the machine's load; see run_offline)")  # fmt: skip
    args = parser.parse_args()
    print(json.dumps(run_offline(args) if args.offline else run(args)), flush=True)


if __name__ == "__main__":
    main()
