"""Collaborative SLAM offline: 2, 3 and 4 agents in the plant, no known start poses, one JSON line and a plot each.

The fleet (:data:`AGENTS`; a configuration of n agents takes the first n): four robots in the west hall's clear
area (7.2 × 5.2 m), each driving a route of the simulator's registry from its own start, exported once per scene,
resolution and rate into ``FLEETSLAM_BENCH_CACHE`` (default ``~/.cache/fleetslam/bench``):

- ``c3po``: ``loop_revisit`` (6 × 4 m, anticlockwise) from the south-west corner heading east;
- ``r2d2``: ``loop_revisit`` from the north-east corner heading west: the same loop half a lap ahead, so every
  aisle of it is seen by both agents about 20 s apart (as the live demo's shared patrol,
  ``launch.demo_plan.SHARED_PATROL_STARTS``);
- ``bb8``: ``survey`` (lawn-mower, four 5 m lanes 1 m apart) from 1 m north of c3po, heading east: it leaves beside
  c3po (the simultaneous case), then sweeps the loop's inside in alternate directions and ends on the loop's north
  side, which r2d2 drove 40 s before;
- ``k2so``: ``figure_eight`` (4.5 × 3.4 m) from the loop's east side heading north, so its lobes cross the
  others' aisles: it sees their places from other directions and at other times.

In every configuration each agent overlaps every other (ground truth, below: over the overlapping pairs of frames
of two agents, the median time between the two views is 13–28 s and the mean heading difference 15–24°; bb8 and
c3po also overlap at once, leaving side by side). No route was added to the simulator.

**Overlap** (ground truth): agent a's camera at time t sees a place agent b's camera saw at t' ≤ t when the camera
centres are within :data:`OVERLAP_M` (1.5 m) and the optical axes within :data:`OVERLAP_DEG` (45°). The first
overlap of a pair is the earliest such t (over both orders); an agent's is the earliest with any other agent.

Each agent runs its own :class:`~fleetslam.slam.pipeline.SlamPipeline` (the defaults, wheel prior and planar
motion) and :class:`~fleetslam.fusion.collaboration.InterAgentLinker`, side by side, frame by frame, and sends
what the SLAM node sends: every keyframe as a ``KeyframeSummary`` and its graph as ``KeyframeGraph`` deltas (at most
every ``graph_period``, at once after a loop closure), with the inter-agent closures it verified as ``INTER_AGENT``
constraints that the peers take as shared closures; both are CDR-serialised to count their bytes. The linker's
time budget is counted in the thread's CPU time (the machine is shared: wall time would starve it at random).
An agent is placed in the fleet frame (the reference agent's map: the alphabetically first, as the node does) by
its linker's ``fleet_transform`` through any placed peer (:class:`LinkerPlacement`). With ``--joint``, the fleet
back-end node's joint optimisation (:class:`JointPlacement`: a ``FleetGraph`` with GNC, fed by the agents' graph
updates, solving at the node's rate in simulated time) places them too, in the same run (the back-ends only watch
the agents), and its figures go under ``joint``.

Figures per configuration:

- time to first merge: per agent, when it was placed in the fleet frame, minus its first overlap (and when it was
  first placed right, within 0.3 m and 5°, minus the same); per pair, when either side accepted the alignment,
  minus the pair's first overlap (simulated seconds);
- **fleet ATE** (target ≤ 5 cm): every placed agent's whole trajectory (all frames, after its final optimisation),
  placed by its final ``T_fleet_map``, associated with its own ground truth, concatenated and aligned to the truth
  with one SE(3) (COVINS; :func:`fleetslam.eval.fleet_ape`); an unplaced agent is left out and says so;
- each agent's own ATE (own SE(3) alignment) with collaboration, and alone: the peer run, the same agent's pipeline
  with no linker (run once per agent and shared by the configurations);
- placements and alignments against the truth (each map frame where its agent's final trajectory fits the ground
  truth): the error each ended with, the largest, and the time an agent was misplaced (> 0.3 m or 5°) in the fleet
  frame or a pair's accepted alignment was false;
- inter-agent closures against the ground truth (correct within 10 cm and 2°; false beyond 0.3 m or 5°, a wrong
  place rather than an imprecise right one): those verified (each agent's own PnP-verified matches) and those
  believed (in an accepted consistent set at any time, shared ones included, each pair of keyframes once),
  counted, their precision, and the worst believed with the shift they imply in the world;
- bytes per keyframe (summary; mean, max; target ≤ 20 kB) and MB/s per agent (summaries + graph deltas over the
  agent's simulated time; target ≤ 0.1 MB/s);
- the "send everything" peer: the full ``Keyframe`` message as the SLAM node builds it (JPEG colour, PNG depth,
  features, visual words), serialised per keyframe: bytes per keyframe and MB/s per agent.

``collaborative_<n>agents.png``: the placed trajectories in the fleet frame (ground truth dashed, brought into the
fleet frame by the fleet-ATE alignment) and the verified closures (believed and correct green, believed and wrong
red, not believed grey).

Progress on stderr; the JSON line on stdout holds every configuration, whether each target was met, and the wall
and CPU time (all threads; the agents run one after the other in one thread, so on an idle machine the wall time
is about the CPU time).

Usage: python benchmarks/collaborative.py [--agents 2,3,4] [--scene procedural] [--resolution 320x240]
           [--rate 10] [--joint] [--out results/benchmarks]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from fleetslam.datasets import open_source
from fleetslam.datasets.base import RGBDFrame
from fleetslam.eval import ape, fleet_ape
from fleetslam.fusion.alignment import rigid_fit
from fleetslam.fusion.collaboration import InterAgentLinker, SharedClosure
from fleetslam.fusion.fleet_graph import ClosureReport, FleetGraph, FleetSolution
from fleetslam.fusion.fleet_graph_node import FleetGraphConfig, closure_covariance
from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphUpdate
from fleetslam.fusion.keyframe_summary import summarize, summary_fields
from fleetslam.geometry import invert, pose_to_quat, rotation_angle
from fleetslam.msg.conversions import camera_info_msg
from fleetslam.msg.typesys import message_from_dict, serialize
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.node import SlamNodeConfig
from fleetslam.slam.peer_recognition import PeerMatch, closure_information
from fleetslam.slam.pipeline import SlamPipeline
from fleetslam.trajectory import NearestPose, Trajectory

Pose = np.ndarray


@dataclass(frozen=True)
class AgentPlan:
    """A robot of the benchmark fleet: its route and start pose in the plant (world frame, m and rad)."""

    name: str
    route: str
    x: float
    y: float
    yaw: float


#: The fleet; a configuration of n agents takes the first n (see the module docstring for why these).
AGENTS = (
    AgentPlan("c3po", "loop_revisit", -12.0, -7.5, 0.0),
    AgentPlan("r2d2", "loop_revisit", -7.5, -3.5, math.pi),
    AgentPlan("bb8", "survey", -12.5, -6.5, 0.0),
    AgentPlan("k2so", "figure_eight", -7.0, -5.5, math.pi / 2),
)
OVERLAP_M, OVERLAP_DEG = 1.5, 45.0
"""Ground-truth overlap: camera centres within this distance and optical axes within this angle."""
CORRECT_M, CORRECT_DEG = 0.10, 2.0
"""An inter-agent closure is correct when within this of the true relative pose of the two cameras."""
FALSE_M, FALSE_DEG = 0.3, 5.0
"""Beyond this it is false (a wrong place: the next shelf, repeated texture), not an imprecise right one."""
FLEET_ATE_TARGET_M = 0.05
KEYFRAME_BYTES_TARGET = 20_000
RATE_TARGET_BYTES_PER_S = 100_000
NODE = SlamNodeConfig()
"""The SLAM node's defaults: graph period, JPEG quality and the collaboration settings."""


def cache_dir() -> Path:
    return Path(os.environ.get("FLEETSLAM_BENCH_CACHE", Path.home() / ".cache" / "fleetslam" / "bench"))


def export(scene: str, plan: AgentPlan, size: tuple[int, int], hz: float) -> Path:
    """The agent's simulator export (made once, then read from the cache)."""
    name, x, y, yaw = plan.name, plan.x, plan.y, plan.yaw
    out = cache_dir() / "collab" / f"{scene}_{plan.route}_{name}_{x:g}_{y:g}_{yaw:.3f}_{size[0]}x{size[1]}_{hz:g}hz_v1"
    if not (out / "groundtruth.txt").is_file():
        from fleetslam.sim.config import SimConfig
        from fleetslam.sim.export import export_tum

        config = SimConfig.model_validate(
            {"world": {"surfaces": scene}, "robots": [{"name": name, "x": x, "y": y, "yaw": yaw}]}
        )
        progress(f"exporting {out.name}")
        export_tum(
            out, config=config, robot=name, route=plan.route, width=size[0], height=size[1], camera_hz=hz,
            progress=False,
        )  # fmt: skip
    return out


def progress(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


# -- what goes on the wire ------------------------------------------------------------------------------------
def pose_fields(pose: np.ndarray) -> dict[str, Any]:
    translation, quat = pose_to_quat(pose)
    return {
        "position": dict(zip("xyz", map(float, translation), strict=True)),
        "orientation": dict(zip("xyzw", map(float, quat), strict=True)),
    }


def stamp_fields(seconds: float) -> dict[str, int]:
    ns = round(seconds * 1e9)
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def summary_bytes(summary: Any, stamp: float) -> int:
    fields = summary_fields(summary)
    fields["header"] = {"stamp": stamp_fields(stamp), "frame_id": "map"}
    fields["pose"] = pose_fields(summary.pose)
    return len(
        serialize(message_from_dict("fleetslam_msgs/msg/KeyframeSummary", fields), "fleetslam_msgs/msg/KeyframeSummary")
    )


@dataclass(frozen=True)
class InterAgent:
    """A closure this agent verified with a peer, sent in its graph as an ``INTER_AGENT`` constraint."""

    match: PeerMatch
    peer_epoch: int


Constraint = tuple[int, int] | InterAgent


def delta_bytes(agent: str, update: GraphUpdate[Constraint], stamp: float) -> int:
    """The ``KeyframeGraph`` message of an update, as the SLAM node builds it (6×6 information per constraint)."""
    ids = sorted(update.poses)
    constraints = []
    for c in update.constraints:
        if isinstance(c, InterAgent):
            constraints.append(
                {"from_id": c.match.own_id, "to_id": c.match.peer_id, "from_agent": agent,
                 "to_agent": c.match.peer_agent, "kind": 2, "relative": pose_fields(c.match.relative),
                 "information": closure_information(c.match), "to_epoch": c.peer_epoch}
            )  # fmt: skip
        else:
            constraints.append(
                {"from_id": c[0], "to_id": c[1], "from_agent": agent, "to_agent": agent, "kind": 0,
                 "relative": pose_fields(np.eye(4)), "information": np.zeros(36), "to_epoch": 0}
            )  # fmt: skip
    msg = message_from_dict(
        "fleetslam_msgs/msg/KeyframeGraph",
        {
            "header": {"stamp": stamp_fields(stamp), "frame_id": "map"},
            "agent": agent,
            "keyframe_ids": np.asarray(ids, np.uint32),
            "poses": [pose_fields(update.poses[i]) for i in ids],
            "stamps": [stamp_fields(update.stamps[i]) for i in ids],
            "constraints": constraints,
            "sequence": update.sequence,
            "full": update.full,
            "epoch": update.epoch,
        },
    )
    return len(serialize(msg, "fleetslam_msgs/msg/KeyframeGraph"))


def everything_bytes(agent: str, pipeline: SlamPipeline, keyframe_id: int, frame: RGBDFrame, odometry: Any) -> int:
    """The "send everything" peer: the full ``Keyframe`` (images and all) as the SLAM node publishes it."""
    import cv2

    quality = [cv2.IMWRITE_JPEG_QUALITY, NODE.jpeg_quality]
    _, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(frame.rgb[:, :, ::-1]), quality)
    _, png = cv2.imencode(".png", np.clip(np.nan_to_num(frame.depth) * 1000.0, 0, 65535).astype(np.uint16))
    descriptors = np.asarray(odometry.descriptors, np.uint8)
    word_ids, word_weights = pipeline.bag_of_words(keyframe_id)
    header = {"stamp": stamp_fields(frame.stamp), "frame_id": "map"}
    msg = message_from_dict(
        "fleetslam_msgs/msg/Keyframe",
        {
            "header": header, "agent": agent, "id": keyframe_id,
            "pose": pose_fields(pipeline.keyframe_poses()[keyframe_id]),
            "rgb_format": "jpeg", "rgb": jpeg.reshape(-1), "depth_format": "png16_mm", "depth": png.reshape(-1),
            "keypoints": np.asarray(odometry.keypoints, np.float32).reshape(-1),
            "points": np.asarray(odometry.points3d, np.float32).reshape(-1),
            "descriptor_length": int(descriptors.shape[1]), "descriptors": descriptors.reshape(-1),
            "word_ids": word_ids, "word_weights": word_weights,
        },
    )  # fmt: skip
    msg.camera_info = camera_info_msg(pipeline.intrinsics, frame_id="camera", stamp_ns=round(frame.stamp * 1e9))
    return len(serialize(msg, "fleetslam_msgs/msg/Keyframe"))


# -- one agent ------------------------------------------------------------------------------------------------
@dataclass
class Agent:
    plan: AgentPlan
    source: Any
    pipeline: SlamPipeline
    linker: InterAgentLinker | None
    """None: the agent alone (the peer run)."""
    writer: GraphDeltaWriter[Constraint] = field(default_factory=GraphDeltaWriter)
    recognizer: Any = None
    constraints: list[Constraint] = field(default_factory=list)
    """What its graph updates have carried and will carry: append-only, as the node keeps it."""
    pipeline_constraints: int = 0
    inter_agent: list[tuple[str, PeerMatch]] = field(default_factory=list)
    """(peer, match) of every closure it verified."""
    graph_sent_at: float = -math.inf
    graph_changed: bool = False
    summary_sizes: list[int] = field(default_factory=list)
    delta_sizes: list[int] = field(default_factory=list)
    everything_sizes: list[int] = field(default_factory=list)
    keyframe_stamps: dict[int, float] = field(default_factory=dict)
    recognition_ms: list[float] = field(default_factory=list)
    aligned_at: dict[str, float] = field(default_factory=dict)
    """Peer -> when this agent first accepted an alignment with it (simulated s)."""
    alignments: dict[str, list[tuple[float, Pose | None]]] = field(default_factory=dict)
    """Peer -> (when, ``T_ownmap_peermap`` accepted or None) each time it changed."""
    believed: dict[tuple[str, int, int], Pose] = field(default_factory=dict)
    """(peer, own keyframe, peer keyframe) -> ``T_owncamera_peercamera`` of every closure that was in an accepted
    consistent set at some point."""
    published: list[GraphUpdate[Constraint]] = field(default_factory=list)
    """Graph updates sent since the fleet back-ends last observed the fleet (what a fleet back-end node receives)."""
    first_stamp: float | None = None
    last_stamp: float = 0.0

    @property
    def name(self) -> str:
        return self.plan.name


def make_agent(plan: AgentPlan, path: Path, *, collaborate: bool) -> Agent:
    source = open_source(path)
    pipeline = SlamPipeline(SlamConfig(), source, base_camera=getattr(source, "base_camera", None))
    # The budget in this thread's CPU time: on a shared machine wall time would hand out recognition at random.
    linker = InterAgentLinker(plan.name, NODE.collaboration, clock=time.thread_time) if collaborate else None
    return Agent(plan, source, pipeline, linker)


def step_agent(agent: Agent, frame: RGBDFrame, fleet: Sequence[Agent], *, everything: bool) -> None:
    """One frame of one agent: SLAM, what it sends its peers, and the peers' keyframes it has time for."""
    if agent.first_stamp is None:
        agent.first_stamp = frame.stamp
    agent.last_stamp = frame.stamp
    step = agent.pipeline.step(frame)
    if agent.linker is None:
        return
    peers = [a for a in fleet if a is not agent]
    if step.keyframe_id is not None:
        poses = agent.pipeline.keyframe_poses()
        result = step.odometry
        summary = summarize(
            agent.name, step.keyframe_id, round(frame.stamp * 1e9), poses[step.keyframe_id], agent.pipeline.intrinsics,
            result.keypoints, result.points3d, np.asarray(result.descriptors),
            max_features=NODE.collaboration.summary_features, epoch=agent.writer.epoch,
        )  # fmt: skip
        agent.keyframe_stamps[step.keyframe_id] = frame.stamp
        agent.summary_sizes.append(summary_bytes(summary, frame.stamp))
        if everything:
            agent.everything_sizes.append(everything_bytes(agent.name, agent.pipeline, step.keyframe_id, frame, result))
        for peer in peers:
            assert peer.linker is not None
            peer.linker.queue_summary(summary)
        agent.graph_changed = True
    if (agent.linker.queue or agent.linker.shared) and agent.pipeline.loop_closure:
        if agent.recognizer is None:
            agent.recognizer = agent.pipeline.peer_recognizer(
                max_verifications=NODE.collaboration.max_verifications,
                min_off_plane=NODE.collaboration.min_off_plane_inliers,
                quality=NODE.collaboration.closure_quality(),
            )
        start = time.thread_time()
        matches = agent.linker.step(agent.recognizer, agent.pipeline.keyframe_poses())
        agent.recognition_ms.append((time.thread_time() - start) * 1000.0)
        for match in matches:
            agent.inter_agent.append((match.peer_agent, match))
            agent.constraints.append(InterAgent(match, agent.linker.peer(match.peer_agent).epoch))
            agent.graph_changed = True
        for peer_name, state in agent.linker.peers.items():
            alignment = None if state.decision is None else state.decision.alignment
            remember(agent.alignments.setdefault(peer_name, []), frame.stamp, alignment)
            if alignment is None or state.decision is None:
                continue
            agent.aligned_at.setdefault(peer_name, frame.stamp)
            for i in state.decision.inliers:
                c = state.closures.closures[i]
                agent.believed.setdefault((peer_name, c.own_id, c.peer_id), c.relative)
    if agent.graph_changed and (step.loop_closed or frame.stamp - agent.graph_sent_at >= NODE.graph_period):
        send_graph(agent, frame.stamp, peers)


def remember(history: list[tuple[float, Pose | None]], stamp: float, pose: Pose | None) -> None:
    """Append ``pose`` when it differs from the last one remembered (by 1 cm or 0.5°, or being None or not)."""
    last = history[-1][1] if history else None
    if (last is None) != (pose is None) or (last is not None and pose is not None and moved(last, pose, 0.01, 0.5)):
        history.append((stamp, None if pose is None else np.array(pose)))


def moved(a: Pose, b: Pose, metres: float, degrees: float) -> bool:
    difference = invert(a) @ b
    return bool(np.linalg.norm(difference[:3, 3]) > metres or math.degrees(rotation_angle(difference)) > degrees)


def send_graph(agent: Agent, stamp: float, peers: Sequence[Agent]) -> None:
    """The graph delta since the last one, to every peer (with the closures it verified with each)."""
    pipeline = [(int(c.a), int(c.b)) for c in agent.pipeline.constraints()]
    full = len(pipeline) < agent.pipeline_constraints
    if full:  # the pipeline rebuilt its constraints: the node resends the whole graph
        agent.constraints = [c for c in agent.constraints if isinstance(c, InterAgent)]
        agent.pipeline_constraints = 0
    agent.constraints += pipeline[agent.pipeline_constraints :]
    agent.pipeline_constraints = len(pipeline)
    update = agent.writer.update(agent.pipeline.keyframe_poses(), agent.keyframe_stamps, agent.constraints, full=full)
    agent.graph_changed, agent.graph_sent_at = False, stamp
    if update is None:
        return
    agent.delta_sizes.append(delta_bytes(agent.name, update, stamp))
    agent.published.append(update)
    for peer in peers:
        assert peer.linker is not None
        peer.linker.apply_graph(agent.name, update)  # type: ignore[arg-type]
        for c in update.constraints:
            if isinstance(c, InterAgent) and c.match.peer_agent == peer.name and c.peer_epoch == peer.writer.epoch:
                shared = SharedClosure(agent.name, c.match.own_id, c.match.peer_id, c.match.relative, update.epoch)
                peer.linker.receive_shared(shared)


# -- the fleet frame -----------------------------------------------------------------------------------------
class FleetBackend(Protocol):
    """Where the agents' map frames lie in the fleet frame, and their trajectories there (a joint optimiser, later
    ``--joint``, implements the same: observe the fleet after each frame, give the fleet-frame trajectories)."""

    reference: str

    def observe(self, fleet: Sequence[Agent], stamp: float) -> None: ...

    def placed_at(self, agent: str) -> float | None: ...

    def history(self, agent: str) -> list[tuple[float, Pose | None]]:
        """(when, ``T_fleet_map``) each time the agent's placement changed."""
        ...

    def trajectories(self, fleet: Sequence[Agent]) -> dict[str, Trajectory]: ...

    def figures(self) -> dict[str, Any]:
        """What the back-end itself measured (for the JSON line)."""
        ...


class PlacementLog:
    """When each agent was first placed and every change of its placement: what both back-ends record."""

    def __init__(self, reference: str, label: str = "") -> None:
        self.reference = reference
        self.label = label
        """Said after the placement in the progress line."""
        self.first_placed: dict[str, float] = {}
        self.histories: dict[str, list[tuple[float, Pose | None]]] = {}

    def record(self, name: str, stamp: float, transform: Pose | None) -> None:
        """The agent's placement at ``stamp`` (None: not placed)."""
        remember(self.histories.setdefault(name, []), stamp, transform)
        if transform is not None and name not in self.first_placed:
            self.first_placed[name] = stamp
            if name != self.reference:
                progress(f"  {name} placed in the fleet frame at {stamp:.1f} s{self.label}")

    def placed_at(self, agent: str) -> float | None:
        return self.first_placed.get(agent)

    def history(self, agent: str) -> list[tuple[float, Pose | None]]:
        return self.histories.get(agent, [])


class LinkerPlacement(PlacementLog):
    """Each agent placed by its own linker (``fleet_transform`` through any placed peer), as the SLAM nodes do;
    trajectories are each agent's own, moved rigidly by its final placement."""

    def __init__(self, reference: str) -> None:
        super().__init__(reference)
        self.placements: dict[str, Pose] = {}

    def observe(self, fleet: Sequence[Agent], stamp: float) -> None:
        for agent in fleet:
            assert agent.linker is not None
            known = {name: pose for name, pose in self.placements.items() if name != agent.name}
            transform = agent.linker.fleet_transform(self.reference, known)
            if transform is None:
                continue
            self.placements[agent.name] = transform
            self.record(agent.name, stamp, transform)

    def trajectories(self, fleet: Sequence[Agent]) -> dict[str, Trajectory]:
        out = {}
        for agent in fleet:
            placement = self.placements.get(agent.name)
            if placement is not None:
                own = agent.pipeline.result().trajectory
                out[agent.name] = Trajectory(own.stamps, np.einsum("ij,njk->nik", placement, own.poses))
        return out

    def figures(self) -> dict[str, Any]:
        return {}


class JointPlacement(PlacementLog):
    """The fleet back-end node's joint optimisation (:class:`~fleetslam.fusion.fleet_graph.FleetGraph`, GNC over every
    agent's keyframes and the inter-agent closures they published), fed by the agents' graph updates as the node is,
    solving at most at the node's rate (simulated time); each agent placed by its solution's ``T_fleet_map``, and its
    trajectory its own, moved rigidly by the final one (as the fleet map places it from ``/fleet/placements``)."""

    def __init__(self, reference: str) -> None:
        super().__init__(reference, " (joint)")
        c = FleetGraphConfig()
        self.period = 1.0 / c.rate
        self.graph = FleetGraph(
            reference=reference, odometry_sigma=c.odometry_sigma, closure_sigma=c.closure_sigma,
            closure_sigma_floor=c.closure_sigma_floor, inlier_probability=c.inlier_probability,
            coarse_stride=c.coarse_stride, recent_keyframes=c.recent_keyframes, min_closures=c.min_closures,
            min_places=c.min_places, dominance=c.dominance, gnc_budget=c.gnc_budget,
        )  # fmt: skip
        self.solved_at = -math.inf
        self.solves = 0
        self.solve_cpu_s = 0.0
        self.last: FleetSolution | None = None
        """The last solve's outcome."""

    def observe(self, fleet: Sequence[Agent], stamp: float) -> None:
        for agent in fleet:
            for update in agent.published:
                self.graph.apply(agent.name, closure_reports(agent.name, update))
        if stamp - self.solved_at >= self.period:
            self.solve(stamp)

    def solve(self, stamp: float) -> None:
        solution = self.graph.solve()
        if solution is None:
            return
        self.solved_at, self.last = stamp, solution
        self.solves += 1
        self.solve_cpu_s += solution.cpu_seconds
        for name in set(self.histories) | set(solution.placements):
            placement = solution.placements.get(name)
            self.record(name, stamp, None if placement is None else placement.T_fleet_map)

    def trajectories(self, fleet: Sequence[Agent]) -> dict[str, Trajectory]:
        self.solve(max(a.last_stamp for a in fleet))  # the updates sent since the last solve
        out = {}
        for agent in fleet:
            placement = self.graph.solution.get(agent.name)
            if placement is not None:
                own = agent.pipeline.result().trajectory
                out[agent.name] = Trajectory(own.stamps, np.einsum("ij,njk->nik", placement.T_fleet_map, own.poses))
        return out

    def figures(self) -> dict[str, Any]:
        last = self.last
        return {
            "solves": self.solves, "solve_cpu_s": round(self.solve_cpu_s, 1),
            "closures_kept": None if last is None else len(last.kept),
            "closures_rejected": None if last is None else len(last.rejected),
        }  # fmt: skip


def closure_reports(agent: str, update: GraphUpdate[Constraint]) -> GraphUpdate[Any]:
    """The update as the fleet back-end node converts it: its inter-agent closures as ``ClosureReport``."""
    closures = [
        ClosureReport(
            agent,
            c.match.own_id,
            c.match.peer_agent,
            c.match.peer_id,
            c.match.relative,
            c.peer_epoch,
            closure_covariance(closure_information(c.match)),
        )
        for c in update.constraints
        if isinstance(c, InterAgent)
    ]
    return GraphUpdate(update.sequence, update.full, update.poses, update.stamps, closures, update.epoch)


FLEET_BACKENDS: Mapping[str, Callable[[str], FleetBackend]] = {"linkers": LinkerPlacement, "joint": JointPlacement}


# -- running --------------------------------------------------------------------------------------------------
def run_side_by_side(
    fleet: Sequence[Agent], backends: Sequence[FleetBackend], label: str, *, everything: bool
) -> float:
    """Every agent's frames in turn, one each per round, until all sources are done, the back-ends observing the
    fleet after each round (they only watch: the agents run the same whichever are there); returns the wall time."""
    iterators = [iter(a.source.frames(1)) for a in fleet]
    done = [False] * len(fleet)
    t0, frames = time.perf_counter(), 0
    while not all(done):
        stamp = 0.0
        for index, agent in enumerate(fleet):
            if done[index]:
                continue
            frame = next(iterators[index], None)
            if frame is None:
                done[index] = True
                continue
            frames += 1
            stamp = max(stamp, frame.stamp)
            step_agent(agent, frame, fleet, everything=everything)
        for backend in backends:
            backend.observe(fleet, stamp)
        for agent in fleet:
            agent.published.clear()
        if frames and frames % (100 * len(fleet)) < len(fleet):
            progress(f"  {label}: {frames} frames, {stamp:.0f} s simulated, {time.perf_counter() - t0:.0f} s")
    return time.perf_counter() - t0


def first_overlaps(gts: Mapping[str, Trajectory]) -> dict[tuple[str, str], float]:
    """Per pair of agents, the first time one camera saw a place the other's had seen (see ``OVERLAP_*``)."""
    out = {}
    cos_limit = math.cos(math.radians(OVERLAP_DEG))
    for a, b in itertools.combinations(sorted(gts), 2):
        ta, tb = gts[a], gts[b]
        near = np.linalg.norm(ta.positions[:, None, :] - tb.positions[None, :, :], axis=2) <= OVERLAP_M
        facing = ta.poses[:, :3, 2] @ tb.poses[:, :3, 2].T >= cos_limit
        when = np.where(near & facing, np.maximum(ta.stamps[:, None], tb.stamps[None, :]), np.inf)
        if np.isfinite(when).any():
            out[(a, b)] = float(when.min())
    return out


class ClosureError(NamedTuple):
    metres: float
    degrees: float
    world_shift: tuple[float, ...]
    """Where the closure puts the peer's camera minus where it was (world frame, m): a shift along a wall or floor
    by the period of its texture is repeated structure."""


def closure_error(gt_own: NearestPose, gt_peer: NearestPose, stamp_own: float, stamp_peer: float,
                  relative: Pose) -> ClosureError | None:  # fmt: skip
    """How far ``T_owncamera_peercamera`` is from the truth (None: no ground truth there)."""
    w_own, w_peer = gt_own(stamp_own), gt_peer(stamp_peer)
    if w_own is None or w_peer is None:
        return None
    error = invert(invert(w_own) @ w_peer) @ relative
    shift = tuple(round(float(v), 3) for v in (w_own @ relative)[:3, 3] - w_peer[:3, 3])
    return ClosureError(float(np.linalg.norm(error[:3, 3])), math.degrees(rotation_angle(error)), shift)


ClosureKey = tuple[tuple[str, int], tuple[str, int]]


def closure_key(agent: str, own_id: int, peer: str, peer_id: int) -> ClosureKey:
    """A closure between two agents' keyframes, whichever of them verified it."""
    first, second = sorted([(agent, own_id), (peer, peer_id)])
    return first, second


def within(error: tuple[Any, ...], metres: float, degrees: float) -> bool:
    return error[0] <= metres and error[1] <= degrees


def true_map_frame(agent: Agent, gt: NearestPose) -> Pose:
    """``T_world_map``: the agent's final trajectory rigidly fitted to its ground truth."""
    trajectory = agent.pipeline.result().trajectory
    pairs = [(p[:3, 3], w[:3, 3]) for t, p in zip(trajectory.stamps, trajectory.poses, strict=True)
             if (w := gt(float(t))) is not None]  # fmt: skip
    return rigid_fit(np.array([a for a, _ in pairs]), np.array([b for _, b in pairs]))


def history_errors(history: Sequence[tuple[float, Pose | None]], truth: Pose, end: float) -> dict[str, Any]:
    """How far a placement or alignment was from ``truth`` over the run: the largest error, the one it ended with
    (None: never held, or withdrawn at the end), the time it was false (beyond ``FALSE_*``) and when it was first
    right (within them)."""
    errors: list[tuple[float, float]] = []
    false_s, first_right = 0.0, None
    for k, (stamp, pose) in enumerate(history):
        if pose is None:
            continue
        difference = invert(truth) @ pose
        errors.append((float(np.linalg.norm(difference[:3, 3])), math.degrees(rotation_angle(difference))))
        if not within(errors[-1], FALSE_M, FALSE_DEG):
            false_s += (history[k + 1][0] if k + 1 < len(history) else end) - stamp
        elif first_right is None:
            first_right = stamp
    final = errors[-1] if history and history[-1][1] is not None else None
    return {
        "error_final_m": None if final is None else round(final[0], 3),
        "error_final_deg": None if final is None else round(final[1], 2),
        "error_max_m": round(max(e[0] for e in errors), 3) if errors else None,
        "error_max_deg": round(max(e[1] for e in errors), 2) if errors else None,
        "false_s": round(false_s, 1),
        "first_right_s": None if first_right is None else round(first_right, 1),
    }


def own_ate(agent: Agent) -> float:
    return round(ape(agent.source.groundtruth(), agent.pipeline.result().trajectory).rmse, 4)


def run_configuration(
    plans: Sequence[AgentPlan], paths: Mapping[str, Path], alone: Mapping[str, float], args: argparse.Namespace
) -> dict[str, Any]:
    names = [p.name for p in plans]
    reference = min(names)
    fleet = [make_agent(p, paths[p.name], collaborate=True) for p in plans]
    backend = FLEET_BACKENDS[args.backend](reference)
    joint = JointPlacement(reference) if args.joint and args.backend != "joint" else None
    progress(f"{len(fleet)} agents ({', '.join(names)}; fleet frame: {reference}'s map)")
    cpu = time.process_time()
    wall = run_side_by_side(fleet, [backend] if joint is None else [backend, joint], f"{len(fleet)} agents",
                            everything=True)  # fmt: skip
    cpu = time.process_time() - cpu
    gts = {a.name: a.source.groundtruth() for a in fleet}
    nearest = {name: NearestPose(gt, 0.02) for name, gt in gts.items()}
    overlaps = first_overlaps(gts)
    world_map = {a.name: true_map_frame(a, nearest[a.name]) for a in fleet}
    end = max(a.last_stamp for a in fleet)

    record: dict[str, Any] = {
        "agents": len(fleet),
        "names": names,
        "reference": reference,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
    }
    per_agent: dict[str, Any] = {}
    verified: list[ClosureError] = []
    believed: dict[ClosureKey, ClosureError | None] = {}
    """Each closure once (both agents may hold it), keyed by its two keyframes, with its error."""
    stamps = {a.name: a.keyframe_stamps for a in fleet}
    for agent in fleet:
        assert agent.linker is not None
        duration = max(agent.last_stamp - (agent.first_stamp or 0.0), 1e-9)
        overlap = min((t for pair, t in overlaps.items() if agent.name in pair), default=None)
        placed = backend.placed_at(agent.name)
        errors = [
            closure_error(nearest[agent.name], nearest[peer], agent.keyframe_stamps[m.own_id],
                          stamps[peer][m.peer_id], m.relative)
            for peer, m in agent.inter_agent
        ]  # fmt: skip
        judged = [e for e in errors if e is not None]
        verified += judged
        for (peer, own_id, peer_id), relative in agent.believed.items():
            key = closure_key(agent.name, own_id, peer, peer_id)
            if key not in believed and own_id in agent.keyframe_stamps and peer_id in stamps[peer]:
                believed[key] = closure_error(
                    nearest[agent.name], nearest[peer], agent.keyframe_stamps[own_id], stamps[peer][peer_id], relative
                )
        wire = sum(agent.summary_sizes) + sum(agent.delta_sizes)
        placement = history_errors(
            backend.history(agent.name), invert(world_map[reference]) @ world_map[agent.name], end
        )
        right = placement["first_right_s"]
        per_agent[agent.name] = {
            "route": agent.plan.route, "start": [agent.plan.x, agent.plan.y, round(agent.plan.yaw, 3)],
            "frames": len(agent.pipeline.result().trajectory), "keyframes": len(agent.summary_sizes),
            "first_overlap_s": None if overlap is None else round(overlap, 1),
            "placed_at_s": None if placed is None else round(placed, 1),
            "merge_after_overlap_s": (
                None if placed is None or overlap is None or agent.name == reference else round(placed - overlap, 1)
            ),
            "right_merge_after_overlap_s": (
                None if right is None or overlap is None or agent.name == reference else round(right - overlap, 1)
            ),
            "placement": placement,
            "own_ate_alone_m": alone.get(agent.name), "own_ate_collaborating_m": own_ate(agent),
            "summary_bytes_mean": round(float(np.mean(agent.summary_sizes))),
            "summary_bytes_max": int(np.max(agent.summary_sizes)),
            "graph_delta_bytes": sum(agent.delta_sizes), "graph_deltas": len(agent.delta_sizes),
            "wire_bytes_per_keyframe": round(wire / max(len(agent.summary_sizes), 1)),
            "wire_mb_per_s": round(wire / duration / 1e6, 4),
            "everything_bytes_per_keyframe": round(float(np.mean(agent.everything_sizes))),
            "everything_mb_per_s": round(sum(agent.everything_sizes) / duration / 1e6, 4),
            "peer_keyframes_tried": sum(s.recognised for s in agent.linker.peers.values()),
            "peer_keyframes_dropped": agent.linker.dropped,
            "closures_verified": len(judged),
            "closures_verified_correct": sum(within(e, CORRECT_M, CORRECT_DEG) for e in judged),
            "recognition_cpu_ms_mean": round(float(np.mean(agent.recognition_ms)), 1) if agent.recognition_ms else 0.0,
            "decisions": {p: s.decision.reason if s.decision else "no closures" for p, s in agent.linker.peers.items()},
        }  # fmt: skip
    record["per_agent"] = per_agent
    pairs = {}
    for (a, b), overlap_at in sorted(overlaps.items()):
        sides = [x for x in fleet if x.name in (a, b)]
        when = min((x.aligned_at[y.name] for x, y in itertools.permutations(sides, 2) if y.name in x.aligned_at),
                   default=None)  # fmt: skip
        alignment_errors = [
            history_errors(x.alignments.get(y.name, []), invert(world_map[x.name]) @ world_map[y.name], end)
            for x, y in itertools.permutations(sides, 2)
        ]
        pairs[f"{a}-{b}"] = {
            "first_overlap_s": round(overlap_at, 1),
            "alignment_error_final_m": max(
                (e["error_final_m"] for e in alignment_errors if e["error_final_m"] is not None), default=None
            ),
            "alignment_error_max_m": max(
                (e["error_max_m"] for e in alignment_errors if e["error_max_m"] is not None), default=None
            ),
            "false_alignment_s": max(e["false_s"] for e in alignment_errors),
            "aligned_at_s": None if when is None else round(when, 1),
            "aligned_after_overlap_s": None if when is None else round(when - overlap_at, 1),
        }
    record["pairs"] = pairs

    trajectories = backend.trajectories(fleet)
    record["backend"] = {"name": args.backend, **backend.figures()}
    record["placed"] = sorted(trajectories)
    record["all_placed"] = len(trajectories) == len(fleet)
    alignment = None
    if trajectories:
        stats, alignment = fleet_ape({name: (gts[name], trajectories[name]) for name in trajectories})
        record["fleet_ate_m"] = round(stats.rmse, 4)
        record["fleet_ate_max_m"] = round(stats.max, 4)
    judged_believed = [e for e in believed.values() if e is not None]
    for kind, found in (("verified", verified), ("believed", judged_believed)):
        correct = sum(within(e, CORRECT_M, CORRECT_DEG) for e in found)
        record[f"closures_{kind}"] = len(found)
        record[f"closures_{kind}_correct"] = correct
        record[f"closure_precision_{kind}"] = round(correct / len(found), 3) if found else None
        record[f"closures_{kind}_false"] = sum(not within(e, FALSE_M, FALSE_DEG) for e in found)
    worst = sorted(((e, k) for k, e in believed.items() if e is not None), reverse=True)[:5]
    record["believed_worst"] = [
        {
            "closure": f"{a}:{i}-{b}:{j}",
            "error_m": round(e.metres, 3),
            "error_deg": round(e.degrees, 2),
            "world_shift_m": e.world_shift,
        }
        for e, ((a, i), (b, j)) in worst
    ]
    summaries = [s for a in fleet for s in a.summary_sizes]
    record["bytes_per_keyframe_mean"] = round(float(np.mean(summaries)))
    record["bytes_per_keyframe_max"] = int(np.max(summaries))
    record["wire_mb_per_s_max"] = max(v["wire_mb_per_s"] for v in per_agent.values())
    record["everything_bytes_per_keyframe_mean"] = round(float(np.mean([s for a in fleet for s in a.everything_sizes])))
    record["everything_mb_per_s_max"] = max(v["everything_mb_per_s"] for v in per_agent.values())
    record["everything_over_summaries"] = round(
        record["everything_bytes_per_keyframe_mean"] / record["bytes_per_keyframe_mean"], 1
    )
    record["misplaced_s"] = {name: v["placement"]["false_s"] for name, v in per_agent.items()}
    record["targets"] = {
        "fleet_ate_le_5cm": bool(record["all_placed"] and record.get("fleet_ate_m", math.inf) <= FLEET_ATE_TARGET_M),
        "bytes_per_keyframe_le_20kB": record["bytes_per_keyframe_max"] <= KEYFRAME_BYTES_TARGET,
        "mb_per_s_per_agent_le_0.1": record["wire_mb_per_s_max"] * 1e6 <= RATE_TARGET_BYTES_PER_S,
        "all_believed_closures_correct": record["closures_believed_correct"] == record["closures_believed"],
        "no_false_closure_believed": record["closures_believed_false"] == 0,
        "never_misplaced": not any(record["misplaced_s"].values()),
    }
    record["targets_met"] = all(record["targets"].values())
    plot(fleet, trajectories, gts, alignment, believed, Path(args.out) / f"collaborative_{len(fleet)}agents.png")
    if joint is not None:
        record["joint"] = placement_figures(joint, fleet, gts, overlaps, world_map, end)
        joint_trajectories = joint.trajectories(fleet)
        if joint_trajectories:
            _, joint_alignment = fleet_ape({name: (gts[name], joint_trajectories[name]) for name in joint_trajectories})
            plot(fleet, joint_trajectories, gts, joint_alignment, believed,
                 Path(args.out) / f"collaborative_{len(fleet)}agents_joint.png")  # fmt: skip
    return record


def placement_figures(
    backend: FleetBackend, fleet: Sequence[Agent], gts: Mapping[str, Trajectory],
    overlaps: Mapping[tuple[str, str], float], world_map: Mapping[str, Pose], end: float,
) -> dict[str, Any]:  # fmt: skip
    """The figures that depend on where a back-end placed the agents (for ``--joint``, beside the linkers')."""
    reference = backend.reference
    trajectories = backend.trajectories(fleet)  # first: it takes the updates sent since the last solve
    per_agent: dict[str, dict[str, Any]] = {}
    for agent in fleet:
        overlap = min((t for pair, t in overlaps.items() if agent.name in pair), default=None)
        placed = backend.placed_at(agent.name)
        placement = history_errors(
            backend.history(agent.name), invert(world_map[reference]) @ world_map[agent.name], end
        )
        right = placement["first_right_s"]
        per_agent[agent.name] = {
            "placed_at_s": None if placed is None else round(placed, 1),
            "merge_after_overlap_s": (
                None if placed is None or overlap is None or agent.name == reference else round(placed - overlap, 1)
            ),
            "right_merge_after_overlap_s": (
                None if right is None or overlap is None or agent.name == reference else round(right - overlap, 1)
            ),
            "placement": placement,
        }
    record: dict[str, Any] = {"backend": backend.figures(), "per_agent": per_agent, "placed": sorted(trajectories),
                              "all_placed": len(trajectories) == len(fleet)}  # fmt: skip
    if trajectories:
        stats, _ = fleet_ape({name: (gts[name], trajectories[name]) for name in trajectories})
        record["fleet_ate_m"] = round(stats.rmse, 4)
        record["fleet_ate_max_m"] = round(stats.max, 4)
    record["misplaced_s"] = {name: v["placement"]["false_s"] for name, v in per_agent.items()}
    record["targets"] = {
        "fleet_ate_le_5cm": bool(record["all_placed"] and record.get("fleet_ate_m", math.inf) <= FLEET_ATE_TARGET_M),
        "never_misplaced": not any(record["misplaced_s"].values()),
    }
    return record


def plot(
    fleet: Sequence[Agent], trajectories: Mapping[str, Trajectory], gts: Mapping[str, Trajectory],
    world_fleet: Pose | None, believed: Mapping[ClosureKey, ClosureError | None], path: Path,
) -> None:  # fmt: skip
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 7))
    if not trajectories or world_fleet is None:
        ax.set_title("no agent placed")
    else:
        reference = trajectories[min(trajectories)]
        # The fleet frame is a camera frame (x right, y down, z forward): draw the two axes the robots moved along.
        axes = np.sort(np.argsort(np.ptp(reference.positions, axis=0))[-2:])
        fleet_world = invert(world_fleet)
        colours = dict(zip([a.name for a in fleet], plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
        for name, trajectory in trajectories.items():
            xy = trajectory.positions[:, axes]
            ax.plot(xy[:, 0], xy[:, 1], color=colours[name], lw=1.2, label=f"{name} (estimate)")
            truth = np.einsum("ij,nj->ni", fleet_world[:3, :3], gts[name].positions) + fleet_world[:3, 3]
            ax.plot(truth[:, axes[0]], truth[:, axes[1]], color=colours[name], lw=0.8, ls="--", alpha=0.6)
        keyframes = {a.name: a.pipeline.keyframe_poses() for a in fleet}
        placements = {a.name: trajectories[a.name].poses[0] @ invert(a.pipeline.result().trajectory.poses[0])
                      for a in fleet if a.name in trajectories}  # fmt: skip
        for agent in fleet:
            for peer, match in agent.inter_agent:
                if agent.name not in placements or peer not in placements:
                    continue
                a = (placements[agent.name] @ keyframes[agent.name][match.own_id])[axes, 3]
                b = (placements[peer] @ keyframes[peer][match.peer_id])[axes, 3]
                error = believed.get(closure_key(agent.name, match.own_id, peer, match.peer_id))
                colour = (
                    "grey" if error is None else "green" if within(error, CORRECT_M, CORRECT_DEG)
                    else "orange" if within(error, FALSE_M, FALSE_DEG) else "red"
                )  # fmt: skip
                ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=0.8, alpha=0.8)
        unplaced = [a.name for a in fleet if a.name not in trajectories]
        ax.set_title(
            f"{len(fleet)} agents in the fleet frame ({min(trajectories)}'s map); ground truth dashed"
            + (f"; not placed: {', '.join(unplaced)}" if unplaced else "")
        )
        ax.set_xlabel(f"fleet {'xyz'[axes[0]]} (m)")
        ax.set_ylabel(f"fleet {'xyz'[axes[1]]} (m)")
        ax.set_aspect("equal")
        ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_alone(plan: AgentPlan, path: Path) -> float:
    """The peer: the agent's own ATE with no collaboration at all."""
    agent = make_agent(plan, path, collaborate=False)
    run_side_by_side([agent], [], f"{plan.name} alone", everything=False)
    return own_ate(agent)


def run(args: argparse.Namespace) -> dict[str, Any]:
    width, height = (int(v) for v in args.resolution.split("x"))
    counts = sorted({int(n) for n in args.agents.split(",")})
    if not counts or min(counts) < 2 or max(counts) > len(AGENTS):
        raise SystemExit(f"--agents: between 2 and {len(AGENTS)} agents, got {args.agents}")
    t0 = time.perf_counter()
    plans = AGENTS[: max(counts)]
    paths = {p.name: export(args.scene, p, (width, height), args.rate) for p in plans}
    alone = {}
    for plan in plans if args.alone else ():
        alone[plan.name] = run_alone(plan, paths[plan.name])
        progress(f"{plan.name} alone: ATE {alone[plan.name] * 100:.1f} cm")
    configurations = []
    for n in counts:
        configurations.append(run_configuration(AGENTS[:n], paths, alone, args))
        c = configurations[-1]
        progress(f"{n} agents: fleet ATE {c.get('fleet_ate_m')} m, placed {c['placed']}, targets {c['targets']}")
    return {
        "benchmark": "collaborative", "scene": args.scene, "resolution": args.resolution, "rate_hz": args.rate,
        "backend": args.backend, "joint": args.joint,
        "overlap": f"camera centres <= {OVERLAP_M} m, optical axes <= {OVERLAP_DEG} deg",
        "closure_correct": f"<= {CORRECT_M} m and {CORRECT_DEG} deg", "configurations": configurations,
        "targets_met": all(c["targets_met"] for c in configurations), "wall_s": round(time.perf_counter() - t0, 1),
        "cpu_s": round(time.process_time(), 1),
    }  # fmt: skip


def main() -> None:
    import cv2

    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", default="2,3,4", help="fleet sizes to run, comma-separated (2 to 4)")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--scene", default="procedural", choices=("procedural", "photographic"))
    parser.add_argument("--backend", default="linkers", choices=sorted(FLEET_BACKENDS), help=argparse.SUPPRESS)
    # The peer runs (each agent alone) are the same in every run: a second run may skip them (own_ate_alone_m null).
    parser.add_argument("--no-alone", dest="alone", action="store_false", help=argparse.SUPPRESS)
    parser.add_argument(
        "--joint", action="store_true",
        help="also place the agents by the fleet back-end's joint optimisation (FleetGraph, GNC) in the same run: "
        "its figures under 'joint' in each configuration",
    )  # fmt: skip
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args()
    print(json.dumps(run(args)), flush=True)


if __name__ == "__main__":
    main()
