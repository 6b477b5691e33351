"""Collaborative SLAM offline: two agents in the plant, no known start poses, one JSON line and a plot.

Two robots drive routes through the same part of the simulated plant from different start poses (each exported
once into ``FLEETSLAM_BENCH_CACHE``). Each runs its own SLAM pipeline (the defaults, wheel prior and planar motion);
they run side by side, frame by frame, and exchange what they would send on the wire: every keyframe as a
``KeyframeSummary`` and the keyframe graph as deltas (both serialised as CDR to count their bytes). Each agent's
:class:`~fleetslam.fusion.collaboration.InterAgentLinker` recognises the other's keyframes in its memory within
its time budget and decides when the closures agree.

Figures: bytes per keyframe summary (mean, max), the wire rate per agent (summaries + graph deltas, over the
run's simulated time), CPU time of recognising peer keyframes per step (the thread's, one core), closures
verified, closures believed (in the accepted consistent set) and how many of those are wrong against the ground
truth (> 0.3 m or 5° from the true relative pose), the alignment error of
``T_mapa_mapb`` against the truth (each SLAM trajectory SE(3)-aligned to its ground truth gives the true map
frames), and when the alignment came (s of simulated time). Targets (issue 14): ≤ 20 kB per keyframe, ≤ 0.1 MB/s
per agent, 0 wrong closures believed. ``collab_slam.png``: both trajectories in the first agent's map frame,
placed by the estimated alignment, with the closures (believed green, rejected grey, wrong red).

Usage: python benchmarks/collab_slam.py [--route loop_revisit] [--resolution 320x240] [--rate 10]
           [--scene procedural] [--out results/benchmarks]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.datasets import open_source
from fleetslam.datasets.base import Intrinsics
from fleetslam.fusion.alignment import rigid_fit
from fleetslam.fusion.collaboration import InterAgentLinker
from fleetslam.fusion.graph_exchange import GraphDeltaWriter
from fleetslam.fusion.keyframe_summary import summarize, summary_fields
from fleetslam.geometry import invert, pose_to_quat, rotation_angle
from fleetslam.msg.typesys import message_from_dict, serialize
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.pipeline import SlamPipeline
from fleetslam.trajectory import NearestPose, Trajectory

#: (name, x, y, yaw) start poses in the plant: the same part of the west hall, entered from opposite corners.
AGENTS = (("c3po", -12.0, -7.5, 0.0), ("r2d2", -7.5, -3.5, float(np.pi)))
WRONG_M, WRONG_RAD = 0.3, float(np.radians(5.0))


def cache_dir() -> Path:
    return Path(os.environ.get("FLEETSLAM_BENCH_CACHE", Path.home() / ".cache" / "fleetslam" / "bench"))


def export(scene: str, route: str, name: str, x: float, y: float, yaw: float, size: tuple[int, int], hz: float) -> Path:
    out = cache_dir() / "collab" / f"{scene}_{route}_{name}_{x:g}_{y:g}_{yaw:.3f}_{size[0]}x{size[1]}_{hz:g}hz_v1"
    if not (out / "groundtruth.txt").is_file():
        from fleetslam.sim.config import SimConfig
        from fleetslam.sim.export import export_tum

        config = SimConfig.model_validate(
            {"world": {"surfaces": scene}, "robots": [{"name": name, "x": x, "y": y, "yaw": yaw}]}
        )
        print(f"exporting {out.name}", file=sys.stderr, flush=True)
        export_tum(out, config=config, robot=name, route=route, width=size[0], height=size[1], camera_hz=hz)
    return out


def pose_fields(pose: np.ndarray) -> dict[str, Any]:
    translation, quat = pose_to_quat(pose)
    return {
        "position": dict(zip("xyz", map(float, translation), strict=True)),
        "orientation": dict(zip("xyzw", map(float, quat), strict=True)),
    }


def summary_bytes(summary: Any) -> int:
    fields = summary_fields(summary)
    fields["header"] = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "map"}
    fields["pose"] = pose_fields(summary.pose)
    return len(
        serialize(message_from_dict("fleetslam_msgs/msg/KeyframeSummary", fields), "fleetslam_msgs/msg/KeyframeSummary")
    )


def delta_bytes(agent: str, update: Any) -> int:
    ids = sorted(update.poses)
    constraint = {
        "from_agent": agent, "to_agent": agent, "relative": pose_fields(np.eye(4)), "information": np.zeros(36),
    }  # fmt: skip
    msg = message_from_dict(
        "fleetslam_msgs/msg/KeyframeGraph",
        {
            "agent": agent,
            "keyframe_ids": np.asarray(ids, np.uint32),
            "stamps": [{"sec": int(update.stamps[i]), "nanosec": 0} for i in ids],
            "poses": [pose_fields(update.poses[i]) for i in ids],
            "constraints": [dict(constraint, from_id=int(a), to_id=int(b)) for a, b in update.constraints],
        },
    )
    return len(serialize(msg, "fleetslam_msgs/msg/KeyframeGraph"))


@dataclass
class Agent:
    name: str
    source: Any
    pipeline: SlamPipeline
    linker: InterAgentLinker
    writer: GraphDeltaWriter[tuple[int, int]] = field(default_factory=GraphDeltaWriter)
    recognizer: Any = None
    summary_sizes: list[int] = field(default_factory=list)
    delta_sizes: list[int] = field(default_factory=list)
    keyframe_stamps: dict[int, float] = field(default_factory=dict)
    aligned_at: float | None = None
    recognition_ms: list[float] = field(default_factory=list)


def make_agent(name: str, path: Path) -> Agent:
    import cv2

    cv2.setNumThreads(1)
    source = open_source(path)
    pipeline = SlamPipeline(SlamConfig(), source, base_camera=getattr(source, "base_camera", None))
    return Agent(name, source, pipeline, InterAgentLinker(name))


def run(args: argparse.Namespace) -> dict[str, Any]:
    size = tuple(int(v) for v in args.resolution.split("x"))
    agents = [
        make_agent(name, export(args.scene, args.route, name, x, y, yaw, size, args.rate))  # type: ignore[arg-type]
        for name, x, y, yaw in AGENTS
    ]
    iterators = [iter(a.source.frames(1)) for a in agents]
    t0, done = time.perf_counter(), [False, False]
    frames = 0
    last_stamp = 0.0
    while not all(done):
        for index, agent in enumerate(agents):
            if done[index]:
                continue
            frame = next(iterators[index], None)
            if frame is None:
                done[index] = True
                continue
            frames += 1
            last_stamp = max(last_stamp, frame.stamp)
            step = agent.pipeline.step(frame)
            other = agents[1 - index]
            if step.keyframe_id is not None:
                poses = agent.pipeline.keyframe_poses()
                intrinsics: Intrinsics = agent.pipeline.intrinsics
                result = step.odometry
                summary = summarize(
                    agent.name, step.keyframe_id, round(frame.stamp * 1e9), poses[step.keyframe_id], intrinsics,
                    result.keypoints, result.points3d, np.asarray(result.descriptors), epoch=agent.writer.epoch,
                )  # fmt: skip
                agent.keyframe_stamps[step.keyframe_id] = frame.stamp
                agent.summary_sizes.append(summary_bytes(summary))
                other.linker.queue_summary(summary)
                constraints = [(int(c.a), int(c.b)) for c in agent.pipeline.constraints()]
                update = agent.writer.update(poses, agent.keyframe_stamps, constraints)
                if update is not None:
                    agent.delta_sizes.append(delta_bytes(agent.name, update))
                    other.linker.apply_graph(agent.name, update)  # type: ignore[arg-type]
            if agent.linker.queue and agent.pipeline.loop_closure:
                if agent.recognizer is None:
                    agent.recognizer = agent.pipeline.peer_recognizer()
                own_poses = agent.pipeline.keyframe_poses()
                start = time.thread_time()
                agent.linker.step(agent.recognizer, own_poses)
                agent.recognition_ms.append((time.thread_time() - start) * 1000.0)
                if agent.aligned_at is None and agent.linker.alignment(other.name) is not None:
                    agent.aligned_at = frame.stamp
        if frames % 200 < 2:
            print(f"  {frames} frames, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return evaluate(agents, last_stamp, args)


def true_map_frame(agent: Agent) -> np.ndarray:
    """``T_world_map`` from the agent's keyframes SE(3)-aligned to its ground truth."""
    gt: Trajectory = agent.source.groundtruth()
    nearest = NearestPose(gt, 0.02)
    poses = agent.pipeline.keyframe_poses()
    est, truth = [], []
    for kid, stamp in agent.keyframe_stamps.items():
        world = nearest(stamp)
        if world is not None and kid in poses:
            est.append(poses[kid][:3, 3])
            truth.append(world[:3, 3])
    return rigid_fit(np.asarray(est), np.asarray(truth))


def evaluate(agents: list[Agent], duration: float, args: argparse.Namespace) -> dict[str, Any]:
    world_map = {a.name: true_map_frame(a) for a in agents}
    gts = {a.name: NearestPose(a.source.groundtruth(), 0.02) for a in agents}
    record: dict[str, Any] = {
        "benchmark": "collab_slam", "scene": args.scene, "route": args.route, "resolution": args.resolution,
        "rate_hz": args.rate, "duration_s": round(duration, 1),
    }  # fmt: skip
    sizes = [s for a in agents for s in a.summary_sizes]
    record["summary_bytes_mean"] = round(float(np.mean(sizes)))
    record["summary_bytes_max"] = int(np.max(sizes))
    wrong_total = 0
    wrong_of: dict[str, set[int]] = {}
    for agent in agents:
        other = next(a for a in agents if a is not agent)
        state = agent.linker.peers.get(other.name)
        decision = state.decision if state is not None else None
        closures = state.closures.closures if state is not None else []
        believed = set(decision.inliers) if decision is not None and decision.alignment is not None else set()
        wrong = []
        for index, closure in enumerate(closures):
            stamp_own = agent.keyframe_stamps.get(closure.own_id)
            stamp_peer = other.keyframe_stamps.get(closure.peer_id)
            if stamp_own is None or stamp_peer is None:
                continue
            w_own, w_peer = gts[agent.name](stamp_own), gts[other.name](stamp_peer)
            if w_own is None or w_peer is None:
                continue
            truth = invert(w_own) @ w_peer
            error = invert(truth) @ closure.relative
            if np.linalg.norm(error[:3, 3]) > WRONG_M or rotation_angle(error) > WRONG_RAD:
                wrong.append(index)
        wrong_of[agent.name] = set(wrong)
        wrong_believed = len(believed & set(wrong))
        wrong_total += wrong_believed
        wire = (sum(agent.summary_sizes) + sum(agent.delta_sizes)) / max(duration, 1e-9)
        prefix = agent.name
        record[f"{prefix}_wire_bytes_per_s"] = round(wire)
        record[f"{prefix}_keyframes"] = len(agent.summary_sizes)
        record[f"{prefix}_peer_keyframes_tried"] = state.recognised if state else 0
        record[f"{prefix}_closures_verified"] = len(closures)
        record[f"{prefix}_closures_wrong_verified"] = len(wrong)
        record[f"{prefix}_closures_believed"] = len(believed)
        record[f"{prefix}_closures_wrong_believed"] = wrong_believed
        record[f"{prefix}_recognition_ms_mean"] = (
            round(float(np.mean(agent.recognition_ms)), 1) if agent.recognition_ms else 0.0
        )
        record[f"{prefix}_queue_dropped"] = agent.linker.dropped
        record[f"{prefix}_decision"] = decision.reason if decision is not None else "no closures"
        alignment = agent.linker.alignment(other.name)
        if alignment is not None:
            truth = invert(world_map[agent.name]) @ world_map[other.name]
            error = invert(truth) @ alignment
            record[f"{prefix}_alignment_error_m"] = round(float(np.linalg.norm(error[:3, 3])), 3)
            record[f"{prefix}_alignment_error_deg"] = round(float(np.degrees(rotation_angle(error))), 2)
            record[f"{prefix}_aligned_at_s"] = round(float(agent.aligned_at or 0.0), 1)
    record["wire_kb_per_keyframe_target_met"] = record["summary_bytes_max"] <= 20_000
    record["wire_rate_target_met"] = all(record[f"{a.name}_wire_bytes_per_s"] <= 100_000 for a in agents)
    record["wrong_closures_believed"] = wrong_total
    record["aligned"] = all(f"{a.name}_alignment_error_m" in record for a in agents)
    plot(agents, world_map, wrong_of[agents[0].name], Path(args.out) / "collab_slam.png")
    return record


def plot(agents: list[Agent], world_map: dict[str, np.ndarray], wrong: set[int], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first, second = agents
    fig, ax = plt.subplots(figsize=(7, 6))
    alignment = first.linker.alignment(second.name)
    placed = alignment if alignment is not None else invert(world_map[first.name]) @ world_map[second.name]
    # The map frame is a camera frame (x right, y down, z forward): draw the two axes the robots moved along.
    own_positions = np.array([p[:3, 3] for p in first.pipeline.keyframe_poses().values()])
    axes = np.sort(np.argsort(np.ptp(own_positions, axis=0))[-2:])
    for agent, frame, colour in ((first, np.eye(4), "tab:blue"), (second, placed, "tab:orange")):
        poses = agent.pipeline.keyframe_poses()
        xy = np.array([(frame @ poses[k])[axes, 3] for k in sorted(poses)])
        ax.plot(xy[:, 0], xy[:, 1], color=colour, label=f"{agent.name} keyframes")
    state = first.linker.peers.get(second.name)
    if state is not None:
        believed = set(state.decision.inliers) if state.decision and state.decision.alignment is not None else set()
        own, other = first.pipeline.keyframe_poses(), second.pipeline.keyframe_poses()
        for index, c in enumerate(state.closures.closures):
            if c.own_id in own and c.peer_id in other:
                a, b = own[c.own_id][axes, 3], (placed @ other[c.peer_id])[axes, 3]
                colour = "red" if index in wrong else "green" if index in believed else "grey"
                ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=1)
    ax.set_aspect("equal")
    placed_by = "the estimated" if alignment is not None else "the TRUE"
    ax.set_title(f"{first.name}'s map: {second.name} placed by {placed_by} alignment")
    ax.set_xlabel(f"map {'xyz'[axes[0]]} (m)")
    ax.set_ylabel(f"map {'xyz'[axes[1]]} (m)")
    ax.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--route", default="loop_revisit")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--scene", default="procedural", choices=("procedural", "photographic"))
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args()
    print(json.dumps(run(args)), flush=True)


if __name__ == "__main__":
    main()
