"""The fleet back-end node: every agent's ``graph_updates`` in, the jointly optimised placements and paths out.

Agents are found in the graph (any ``/<agent>/graph_updates`` publisher) or listed in the parameters. Each agent's
updates (deltas, numbered) feed a :class:`~fleetslam.fusion.fleet_graph.FleetGraph`; a gap (a lost message, a
back-end that started late) asks the agent for its whole graph (``/<agent>/graph/full``, off the middleware's
thread, one request per agent at a time), as the agents do with each other. A worker thread drains what came in
and re-optimises when something changed, at most ``rate`` times a second and within ``max_load`` of one core; after
each solve it publishes ``/fleet/placements`` (tf2_msgs/TFMessage, latched: ``fleet → <agent>/map`` of every agent
placed; the fleet map node prefers these to the agents' own ``slam/fleet_transform``), ``/fleet/backend/diagnostics``
(agents placed, closures kept and rejected, variables, solve time) and, to whoever subscribes, ``/<agent>/fleet_path``
(nav_msgs/Path of the agent's corrected keyframes in the fleet frame, each stamped with its keyframe's stamp).

Nothing flows back to the agents' SLAM: an agent keeps mapping in its own frame whatever happens here (cut off,
back-end restarted), and the back-end catches up from the agents' graphs when they come back. An agent's mapping node
may follow its ``fleet_path`` (``follow_fleet``: its keyframes integrated where the solve put them, see
:mod:`fleetslam.fusion.fleet_correction`), and goes on from its own graph when the paths stop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fleetslam import topics
from fleetslam.config import ConfigModel
from fleetslam.errors import MessageError, worth_logging
from fleetslam.fusion.consistency import ConsistencyTolerance
from fleetslam.fusion.fleet_graph import ClosureReport, FleetGraph, FleetSolution
from fleetslam.fusion.graph_exchange import GraphUpdate, graph_update_of
from fleetslam.fusion.graph_fetcher import GraphFetcher
from fleetslam.middleware import Node
from fleetslam.msg.conversions import path_cdr, pose_matrix, transform_msg
from fleetslam.msg.typesys import get_type, header

log = logging.getLogger(__name__)

INTER_AGENT = 2
"""``GraphConstraint.kind`` of an inter-agent closure."""


class FleetGraphConfig(ConfigModel):
    """Parameters of the fleet back-end node."""

    reference: str = ""
    """The agent whose map frame is the fleet frame; empty: the alphabetically first of ``agents`` when they are
    listed, else of the agents seen (as the agents' SLAM chooses it, ``fleet_reference``)."""
    agents: list[str] = Field(default_factory=list)
    """Agents to optimise; empty: every agent publishing ``graph_updates``."""
    frame_id: str = "fleet"
    """The fleet frame: parent of the placements, frame of the paths."""
    map_frame: str = "map"
    """Each agent's map frame, ``<agent>/<map_frame>`` in the placements."""
    rate: float = Field(default=4.0, gt=0.0)
    """Most solves per second."""
    max_load: float = Field(default=0.6, gt=0.0, le=1.0)
    """Largest share of one core the solves may take: a solve that took t s of CPU time (publishing included; not
    the time spent waiting for a core on a busy machine) is followed by the next one no sooner than t / max_load s
    after it started."""
    odometry_sigma: tuple[float, float] = (0.01, 0.005)
    """Standard deviation (m, rad) of the relative pose of two consecutive keyframes of one agent (its own
    optimised poses; known inliers). Tight: an agent's own chain is far more precise over a keyframe than an
    inter-agent closure, which must not bend it."""
    closure_sigma: tuple[float, float] = (0.05, 0.02)
    """Standard deviation (m, rad) of an inter-agent closure that comes without its covariance (an agent that
    sends none: zeros as its information)."""
    closure_sigma_floor: tuple[float, float] = (0.01, 0.005)
    """Standard deviation (m, rad) added in quadrature to the covariance an agent sent with its closure (the two
    keyframes' own poses are not exact either)."""
    inlier_probability: float = Field(default=0.99, gt=0.0, lt=1.0)
    """GNC (truncated least squares): a closure whose whitened error is beyond this quantile of χ²(6) is an
    outlier."""
    coarse_stride: int = Field(default=5, ge=1)
    """Of an agent's older keyframes every this many is a variable of the solve (and every closure's keyframe);
    those between follow their neighbours' corrections. 1: every keyframe (the solve grows 5 times)."""
    recent_keyframes: int = Field(default=10, ge=1)
    """An agent's newest keyframes that are all variables."""
    gnc_budget: int = Field(default=200, ge=1)
    """Most variables of one solve's GNC. New closures are judged a group of agents at a time (those waiting longest
    first, as many agents as this many of their keyframe variables hold, then their neighbours while it holds; the
    other agents they share closures with are held where they are), the rest in the next solves, so that no solve
    keeps every agent's new keyframes waiting long (a GNC over all 32 agents of ``benchmarks/fleet_backend.py`` took
    0.7 s). At least one closure's two agents. A fleet whose graph fits is judged by one GNC over all of it."""
    min_closures: int = Field(default=3, ge=1)
    """Mutually consistent closures between two agents before they are connected (placed relative to each
    other): the pairwise test the agents use themselves."""
    min_places: int = Field(default=2, ge=1)
    """Distinct places (0.5 m apart) among those closures."""
    dominance: float = Field(default=2.0, ge=1.0)
    """The consistent set must be this many times larger than any set inconsistent with it (repeated structure)."""
    path_tolerance: float = Field(default=0.005, ge=0.0)
    """An agent's ``fleet_path`` is sent again when it has new keyframes or one moved more than this (m)."""
    path_bytes_per_s: float = Field(default=100_000.0, gt=0.0)
    """Most bytes per second of one agent's ``fleet_path``: the link budget of an agent (0.1 MB/s). A path goes out
    whole (about 80 B per keyframe) and is sent again no sooner than its size divided by this after the last send
    (0.16 s at 200 keyframes, 3 s at 4000), so that a long run's paths do not grow the traffic without bound. Lower
    costs latency: at 20 kB/s the scale benchmark's lag went from 0.92 to 1.6 s at most (32 agents of ~200
    keyframes). A follower places the keyframes newer than the path it holds from the newest corrected one (the
    mapping node's ``follow_fleet``)."""
    request_timeout: float = Field(default=5.0, gt=0.0)
    """How long (s) a request for an agent's whole graph may take."""


def fleet_graph(config: FleetGraphConfig) -> FleetGraph:
    """The :class:`FleetGraph` the node solves with ``config``."""
    c = config
    # With the agents listed, the reference is known from the start (the first of them, as their SLAM chooses it):
    # an agent heard before the reference must not become the fleet frame for a moment (a map landed there would
    # jump metres once the reference is heard).
    reference = c.reference or (min(c.agents) if c.agents else "")
    return FleetGraph(
        reference=reference, odometry_sigma=c.odometry_sigma, closure_sigma=c.closure_sigma,
        closure_sigma_floor=c.closure_sigma_floor, inlier_probability=c.inlier_probability,
        coarse_stride=c.coarse_stride, recent_keyframes=c.recent_keyframes,
        tolerance=ConsistencyTolerance(), min_closures=c.min_closures, min_places=c.min_places, dominance=c.dominance,
        gnc_budget=c.gnc_budget,
    )  # fmt: skip


def closure_update(agent: str, msg: Any) -> GraphUpdate[ClosureReport]:
    """``agent``'s ``fleetslam_msgs/KeyframeGraph`` as the fleet graph takes it: its inter-agent closures as
    :class:`ClosureReport` (other constraints are not needed: the agent's own poses hold them). Raises
    :class:`MessageError` (or ``ValueError``, ``TypeError``) when it is malformed."""
    if str(msg.agent) != agent:
        raise MessageError(f"it names agent {str(msg.agent)!r}")
    update = graph_update_of(msg)
    closures = []
    for c in update.constraints:
        if int(c.kind) != INTER_AGENT or str(c.from_agent) != agent:
            continue
        relative = pose_matrix(c.relative)
        if not np.isfinite(relative).all():
            raise MessageError("an inter-agent closure is not finite")
        closures.append(ClosureReport(agent, int(c.from_id), str(c.to_agent), int(c.to_id), relative,
                                      int(c.to_epoch), closure_covariance(c.information)))  # fmt: skip
    return GraphUpdate(update.sequence, update.full, update.poses, update.stamps, closures, update.epoch)


def closure_covariance(information: Any) -> NDArray[np.float64] | None:
    """The covariance of an inter-agent closure from its message's 6×6 information (translation first); None when
    the agent sent none (zeros) or it cannot be inverted (then the back-end's ``closure_sigma`` stands in)."""
    matrix = np.asarray(information, np.float64).reshape(6, 6)
    if not np.isfinite(matrix).all() or not matrix.any():
        return None
    try:
        covariance = np.linalg.inv(0.5 * (matrix + matrix.T))
    except np.linalg.LinAlgError:
        return None
    if not (np.isfinite(covariance).all() and (np.linalg.eigvalsh(covariance) > 0).all()):
        return None
    return np.asarray(covariance, np.float64)


class FleetGraphNode:
    """Adapter between the middleware and a :class:`FleetGraph` (see the module docstring)."""

    def __init__(self, node: Node, config: FleetGraphConfig | None = None) -> None:
        self.node = node
        self.config = config or FleetGraphConfig()
        c = self.config
        self.graph = fleet_graph(c)
        self.solution: FleetSolution | None = None
        """The last solve's outcome."""
        self.solves = 0
        self.solve_seconds: list[float] = []
        """Wall time of the last solves (at most 1000)."""
        self.counts = {"updates": 0, "bad_messages": 0, "graph_requests": 0}
        self._inbox: deque[tuple[str, GraphUpdate[ClosureReport]]] = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._subscribed: set[str] = set()
        self._graph_fetcher = GraphFetcher(
            node.create_client, self.on_graph_update, name=node.fq_name, timeout=self.config.request_timeout
        )
        self._asked: dict[str, float] = {}
        """When each agent's whole graph was last asked for (monotonic s)."""
        self._path_pubs: dict[str, Any] = {}
        self._path_published: dict[str, tuple[list[int], np.ndarray, float]] = {}
        """Per agent, the keyframe ids and positions of the path last sent and when the next may go out."""
        placements = topics.FLEET_PLACEMENTS
        self.placements_pub = node.create_publisher(placements.type, placements.name, placements.qos())
        diagnostics = topics.FLEET_BACKEND_DIAGNOSTICS
        self.diagnostics_pub = node.create_publisher(diagnostics.type, diagnostics.name, diagnostics.qos())
        for agent in c.agents:
            self._subscribe(agent)
        node.create_timer(1.0, self._discover)
        self._worker = threading.Thread(target=self._work, name=f"{node.fq_name}/fleet-graph", daemon=True)
        self._worker.start()
        node.add_on_destroy(self.close)

    def close(self) -> None:
        """Stop the worker (it finishes the solve it is in)."""
        self._stop.set()
        self._wake.set()
        if self._worker is not threading.current_thread():
            self._worker.join(10.0)

    # -- inputs -------------------------------------------------------------------------------------------------
    def _discover(self) -> None:
        if self.config.agents:
            return
        for topic in self.node.context.graph.topic_names_and_types():
            parts = topic.strip("/").split("/")
            if len(parts) == 2 and parts[1] == topics.GRAPH_UPDATES.name and parts[0] != "fleet":
                self._subscribe(parts[0])

    def _subscribe(self, agent: str) -> None:
        if agent in self._subscribed:
            return
        self._subscribed.add(agent)
        updates = topics.GRAPH_UPDATES
        self.node.create_subscription(updates.type, updates.of(agent), partial(self.on_graph_update, agent),
                                      updates.qos(depth=updates.depth))  # fmt: skip
        self._graph_fetcher.add(agent)
        path = topics.FLEET_PATH
        self._path_pubs[agent] = self.node.create_publisher(path.type, path.of(agent), path.qos())
        log.info("fleet back-end: following %s", agent)

    def on_graph_update(self, agent: str, msg: Any) -> None:
        """An agent's graph update (or whole graph), queued for the worker."""
        update = self._convert(agent, msg)
        if update is not None:
            self._inbox.append((agent, update))
            self._wake.set()

    def _convert(self, agent: str, msg: Any) -> GraphUpdate[ClosureReport] | None:
        """The update as :func:`closure_update` makes it; None when malformed (counted, logged)."""
        try:
            return closure_update(agent, msg)
        except (MessageError, ValueError, TypeError) as err:
            self.counts["bad_messages"] += 1
            n = self.counts["bad_messages"]
            if worth_logging(n):
                log.warning("fleet back-end: graph update from %s ignored (%d so far): %s", agent, n, err)
            return None

    def _request_graph(self, agent: str) -> None:
        """Ask ``agent`` for its whole graph, off the worker (one request per agent at a time)."""
        if self._graph_fetcher.request(agent):
            self.counts["graph_requests"] += 1

    # -- work ---------------------------------------------------------------------------------------------------
    def _work(self) -> None:
        next_solve = 0.0
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            self._drain()
            wait = next_solve - time.monotonic()
            if wait > 0.0:
                if self._stop.wait(wait):
                    return
                self._drain()
            if not self.graph.changed:
                self.publish_paths()  # to a viewer that subscribed since
                continue
            started, started_cpu = time.monotonic(), time.thread_time()
            try:
                self.step()
            except Exception as err:  # a numerical failure must not stop the back-end: the next change retries
                log.warning("fleet back-end: solve failed: %s", err)
            # The CPU time the solve and its publishing took: on a busy machine the wall time also counts the waits
            # for a core, which are not the back-end's load, and spacing the solves by them kept every agent's new
            # keyframes waiting longer still.
            took = time.thread_time() - started_cpu
            next_solve = started + max(1.0 / self.config.rate, took / self.config.max_load)

    def _drain(self) -> None:
        while self._inbox:
            agent, update = self._inbox.popleft()
            self.counts["updates"] += 1
            self.graph.apply(agent, update)
        # A gap asks for the whole graph; a request that failed (the service not found yet, the agent away) is
        # repeated every request_timeout while the gap lasts, since no later update may come to ask again.
        now = time.monotonic()
        for agent in self.graph.unsynced():
            if now - self._asked.get(agent, -np.inf) >= self.config.request_timeout:
                self._asked[agent] = now
                self._request_graph(agent)

    def step(self) -> FleetSolution | None:
        """Solve if something changed and publish the outcome (the worker calls this; a test may too)."""
        solution = self.graph.solve()
        if solution is None:
            return None
        before = self.solution
        self.solution = solution
        self.solves += 1
        self.solve_seconds.append(solution.seconds)
        del self.solve_seconds[:-1000]
        placed = set(solution.placements)
        if before is None or set(before.placements) != placed or len(before.rejected) != len(solution.rejected):
            log.info("fleet back-end: %d agents placed (%s), %d closures kept, %d rejected, %d variables, %.2f s",
                     len(solution.placements), ", ".join(sorted(solution.placements)), len(solution.kept),
                     len(solution.rejected), solution.keyframes, solution.seconds)  # fmt: skip
        self.publish(solution)
        self.publish_diagnostics(solution)
        return solution

    def publish_diagnostics(self, solution: FleetSolution) -> None:
        """``/fleet/backend/diagnostics``: one status named ``fleet_backend`` with this solve's figures."""
        values = {
            "agents_known": len(self.graph.agents), "agents_placed": len(solution.placements),
            "closures_kept": len(solution.kept), "closures_rejected": len(solution.rejected),
            "closures_pending": len(solution.pending),
            "variables": solution.keyframes, "robust": solution.robust, "solve_ms": round(solution.seconds * 1e3, 1),
            "solve_cpu_ms": round(solution.cpu_seconds * 1e3, 1),
            "solves": self.solves, **self.counts,
        }  # fmt: skip
        status_type = get_type("diagnostic_msgs/msg/DiagnosticStatus")
        status = status_type(
            level=status_type.OK, name="fleet_backend", hardware_id=self.config.frame_id,
            message=f"{len(solution.placements)} of {len(self.graph.agents)} agents placed",
            values=[get_type("diagnostic_msgs/msg/KeyValue")(key=k, value=str(v)) for k, v in values.items()],
        )  # fmt: skip
        self.diagnostics_pub.publish(get_type("diagnostic_msgs/msg/DiagnosticArray")(
            header=header(self.config.frame_id, self.node.now_ns()), status=[status]))  # fmt: skip

    def publish(self, solution: FleetSolution) -> None:
        """``/fleet/placements`` (always: latched), each agent's ``fleet_path`` while someone subscribes."""
        now_ns = self.node.now_ns()
        transforms = [
            transform_msg(placement.T_fleet_map, self.config.frame_id, f"{agent}/{self.config.map_frame}",
                          now_ns).transforms[0]
            for agent, placement in sorted(solution.placements.items())
        ]  # fmt: skip
        self.placements_pub.publish(get_type("tf2_msgs/msg/TFMessage")(transforms=transforms))
        self.publish_paths()

    def publish_paths(self) -> None:
        """Each placed agent's corrected keyframes, to whoever subscribes, when it has keyframes not sent yet or one
        of them moved more than ``path_tolerance`` since its path was last sent (a solve nudges every keyframe by
        fractions of a millimetre; resending 32 paths for that would cost more than the solve), within
        ``path_bytes_per_s``."""
        if self.solution is None:
            return
        now = time.monotonic()
        for agent, placement in self.solution.placements.items():
            publisher = self._path_pubs.get(agent)
            if publisher is None or not publisher.matched_subscriptions:
                continue
            ids = placement.ids.tolist()
            positions = placement.stack[:, :3, 3]
            sent = self._path_published.get(agent)
            if sent is not None and (
                now < sent[2]
                or (sent[0] == ids and (not ids or np.max(np.abs(positions - sent[1])) <= self.config.path_tolerance))
            ):
                continue
            stamps_ns = np.round(placement.stamp_array * 1e9).astype(np.int64)
            data = path_cdr(self.config.frame_id, self.node.now_ns(), placement.stack, stamps_ns)
            publisher.publish_raw(data)
            self._path_published[agent] = (ids, positions, now + len(data) / self.config.path_bytes_per_s)
