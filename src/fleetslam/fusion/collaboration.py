"""One agent's side of collaborative SLAM: peers' keyframes recognised in its memory, closures kept per peer,
and the peers' map frames placed in its own once the closures agree.

:class:`InterAgentLinker` is the pure core a SLAM node drives:

- ``queue_summary``: a peer's :class:`~fleetslam.fusion.keyframe_summary.KeyframeSummary` arrived (bounded queue;
  the oldest of a peer leave first when it floods);
- ``apply_graph``: a peer's graph update arrived (its :class:`~fleetslam.fusion.graph_exchange.GraphMirror`
  tells whether a full graph must be requested);
- ``catch_up_request`` / ``catch_up_answered`` / ``catch_up_failed``: which of a peer's keyframes (in the mirror of
  its graph) came without a summary, to be asked for in small batches (a
  :class:`~fleetslam.fusion.summary_catchup.SummaryCatchUp` per peer; the node makes the calls, off the SLAM thread);
- ``receive_shared``: a closure a peer verified with this agent (it publishes them in its graph), so that an agent
  that joined late, or whose view a peer recognised first, is placed from the peer's evidence too;
- ``step``: from the thread that owns the memory, between frames, verify queued summaries within a time budget;
  each verified match, and each shared closure, becomes a :class:`~fleetslam.fusion.consistency.PairClosure` in
  that peer's :class:`~fleetslam.fusion.consistency.ClosureSet`, whose decision gives ``T_ownmap_peermap``.

Placing the agent in the fleet frame (:meth:`InterAgentLinker.fleet_transform`): the fleet frame is the map frame
of the reference agent (configured; by default the alphabetically first agent of the fleet); an agent aligned with
any peer whose place in the fleet frame is known gets ``T_fleet_ownmap = T_fleet_peermap · T_ownmap_peermap⁻¹``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fleetslam.config import ConfigModel
from fleetslam.fusion.consistency import ClosureSet, ConsistencyTolerance, Decision, PairClosure
from fleetslam.fusion.graph_exchange import GraphMirror, GraphUpdate
from fleetslam.fusion.keyframe_summary import KeyframeSummary
from fleetslam.fusion.summary_catchup import SummaryCatchUp
from fleetslam.geometry import invert
from fleetslam.slam.peer_recognition import MIN_OFF_PLANE_INLIERS, ClosureQuality, PeerMatch, PeerPlaceRecognizer

Pose = NDArray[np.float64]


class CollaborationConfig(ConfigModel):
    """Inter-agent place recognition and alignment."""

    summary_features: int = Field(default=400, ge=20, le=4096)
    """Features per keyframe sent to peers (with depth, spread over the image): ~38 bytes each."""
    max_verifications: int = Field(default=2, ge=1)
    """Own locations verified (PnP both ways) per peer keyframe, the best scored first."""
    min_off_plane_inliers: int = Field(default=MIN_OFF_PLANE_INLIERS, ge=0)
    """PnP inliers of a peer match that must lie off the plane holding most of them (0: no check): a tiled floor
    gives closures shifted by its period that agree with each other."""
    closure_min_spread: float = Field(default=ClosureQuality.min_spread, ge=0.0, le=0.5)
    """A peer closure's refined inliers must spread over at least this fraction of the image in each direction
    (standard deviation of their pixel positions over the image's size; 0.29 for a uniform spread): inliers bunched
    in one small patch far away pin the transform poorly (closures 10–23 cm off had 0.04–0.06)."""
    closure_max_std: float = Field(default=ClosureQuality.max_translation_std, gt=0.0)
    """Largest standard deviation (m) of a peer closure's translation, from its refinement's covariance."""
    closure_max_std_deg: float = Field(default=ClosureQuality.max_rotation_std_deg, gt=0.0)
    """Largest standard deviation (degrees) of a peer closure's rotation, from its refinement's covariance."""
    budget_ms: float = Field(default=15.0, gt=0.0)
    """Time the node gives peer keyframes between two of its own frames; the rest wait in the queue."""
    max_queued: int = Field(default=30, ge=1)
    """Peer keyframes waiting to be recognised, all peers together; the oldest leave first."""
    min_closures: int = Field(default=3, ge=1)
    """Mutually consistent closures with a peer before its map frame is placed in this agent's."""
    min_places: int = Field(default=2, ge=1)
    """Distinct places (``place_spacing``) among those closures: one place seen often is one piece of evidence."""
    place_spacing: float = Field(default=0.5, gt=0.0)
    """Distance (m) between this agent's keyframes that counts them as distinct places."""
    dominance: float = Field(default=2.0, ge=1.0)
    """The consistent set must be this many times larger than any set inconsistent with it (repeated structure)."""
    translation_tolerance: float = Field(default=0.15, gt=0.0)
    """Disagreement (m) allowed between two closures' implied frames at the same place."""
    rotation_tolerance_deg: float = Field(default=3.0, gt=0.0)
    """Disagreement (degrees) allowed between two closures' implied frames at the same place."""
    drift_fraction: float = Field(default=0.05, ge=0.0)
    """Extra disagreement allowed per metre between the two places (both agents' drift)."""
    summary_store: int = Field(default=1000, ge=1)
    """This agent's newest keyframe summaries kept for peers that missed them (~18 kB each at 400 features: 18 MB
    for 1000); older ones are answered as unknown."""
    catch_up: bool = True
    """Ask a peer for the summaries of keyframes its graph names but that never arrived (a link cut, a late join)."""
    catch_up_batch: int = Field(default=8, ge=1, le=64)
    """Summaries per catch-up request (asked and answered: ~15 kB each)."""
    catch_up_period: float = Field(default=0.5, gt=0.0)
    """Shortest time (s) between two catch-up requests to a peer; doubled after each failed one, up to 8 s."""
    catch_up_timeout: float = Field(default=2.0, gt=0.0)
    """How long (s) a catch-up request waits for its answer (a dead link must not hold the requests up longer)."""
    catch_up_grace: float = Field(default=2.0, ge=0.0)
    """A peer keyframe is asked for once its graph has named it this long (s) without its summary arriving."""

    def closure_quality(self) -> ClosureQuality:
        """What a verified peer closure must show to be believed precise (see
        :func:`~fleetslam.slam.peer_recognition.refine_closure`)."""
        return ClosureQuality(
            min_spread=self.closure_min_spread,
            max_translation_std=self.closure_max_std,
            max_rotation_std_deg=self.closure_max_std_deg,
        )


@dataclass(frozen=True)
class SharedClosure:
    """A closure a peer verified with this agent: the peer's keyframe ``peer_id`` sees this agent's ``own_id``."""

    peer: str
    peer_id: int
    own_id: int
    relative: Pose
    """``T_peercamera_owncamera``."""
    epoch: int
    """The peer's run it came from."""


@dataclass
class PeerState:
    """What this agent knows of one peer."""

    mirror: GraphMirror[object] = field(default_factory=GraphMirror)
    closures: ClosureSet = field(default_factory=ClosureSet)
    decision: Decision | None = None
    matches: int = 0
    """Peer keyframes verified against this agent's memory."""
    recognised: int = 0
    """Peer keyframes tried."""
    epoch: int = 0
    """The peer's SLAM run these closures belong to (0: not known yet)."""
    restarts: int = 0
    """Times the peer was seen to restart (a new epoch: its map frame is new, its closures were dropped)."""
    catch_up: SummaryCatchUp = field(default_factory=SummaryCatchUp)
    """The peer's keyframes whose summaries this agent has, and those to ask for."""


class InterAgentLinker:
    """Peers' keyframes in, verified closures and peer alignments out (see the module docstring)."""

    def __init__(
        self, agent: str, config: CollaborationConfig | None = None, *, clock: Callable[[], float] = time.perf_counter
    ) -> None:
        self.agent = agent
        self.config = config or CollaborationConfig()
        self.clock = clock
        self.peers: dict[str, PeerState] = {}
        self.queue: deque[KeyframeSummary] = deque()
        self._queue_lock = threading.Lock()
        """Summaries are queued by the middleware's thread and taken by the one that owns the memory."""
        self.dropped = 0
        """Peer keyframes that left the queue unprocessed (flood or a busy agent)."""
        self.shared: deque[SharedClosure] = deque(maxlen=self.config.max_queued * 4)
        """Closures peers verified with this agent, waiting for the memory's thread (the oldest leave first)."""

    def peer(self, agent: str) -> PeerState:
        """The state of a peer (created on first use)."""
        state = self.peers.get(agent)
        if state is None:
            c = self.config
            tolerance = ConsistencyTolerance(
                translation_m=c.translation_tolerance,
                rotation_rad=float(np.radians(c.rotation_tolerance_deg)),
                drift_fraction=c.drift_fraction,
            )
            closures = ClosureSet(
                tolerance=tolerance, min_inliers=c.min_closures, min_places=c.min_places,
                place_spacing_m=c.place_spacing, dominance=c.dominance,
            )  # fmt: skip
            catch_up = SummaryCatchUp(batch=c.catch_up_batch, period_s=c.catch_up_period, grace_s=c.catch_up_grace)
            state = self.peers[agent] = PeerState(closures=closures, catch_up=catch_up)
        return state

    def _observe_epoch(self, agent: str, epoch: int) -> None:
        """A peer's run changed (it restarted): its map frame is new, so the closures with it and its queued keyframes
        no longer hold."""
        state = self.peer(agent)
        if epoch == state.epoch or epoch == 0:
            return
        state.catch_up.observe_epoch(epoch)
        if state.epoch != 0:
            state.restarts += 1
            state.closures = ClosureSet(
                tolerance=state.closures.tolerance, min_inliers=state.closures.min_inliers,
                min_places=state.closures.min_places, place_spacing_m=state.closures.place_spacing_m,
                dominance=state.closures.dominance, max_closures=state.closures.max_closures,
            )  # fmt: skip
            state.decision = None
            with self._queue_lock:
                self.queue = deque(s for s in self.queue if s.agent != agent or s.epoch == epoch)
                kept = [c for c in self.shared if c.peer != agent or c.epoch == epoch]
                self.shared.clear()
                self.shared.extend(kept)
        state.epoch = epoch

    def queue_summary(self, summary: KeyframeSummary, *, by_catch_up: bool = False) -> None:
        """A peer keyframe to recognise when there is time (this agent's own summaries are ignored); ``by_catch_up``:
        it came as the answer to a catch-up request rather than on the stream."""
        if summary.agent == self.agent:
            return
        self._observe_epoch(summary.agent, summary.epoch)
        state = self.peer(summary.agent)
        if summary.epoch in (0, state.epoch):
            state.catch_up.summary_arrived(summary.keyframe_id, by_catch_up=by_catch_up)
        with self._queue_lock:
            self.queue.append(summary)
            while len(self.queue) > self.config.max_queued:
                self.queue.popleft()
                self.dropped += 1

    def apply_graph(self, agent: str, update: GraphUpdate[object]) -> bool:
        """Apply a peer's graph update; False when the peer's full graph should be requested."""
        self._observe_epoch(agent, update.epoch)
        return self.peer(agent).mirror.apply(update)

    def catch_up_request(self, agent: str, now: float) -> tuple[int, list[int]]:
        """The peer's run and the ids of its keyframes to ask it for now ([] for none: see
        :meth:`SummaryCatchUp.next_request`); at most what fits in half of the recognition queue, so that the
        stream's summaries keep their place. The outcome goes to :meth:`catch_up_answered` or
        :meth:`catch_up_failed`."""
        state = self.peer(agent)
        if not self.config.catch_up or not state.mirror.synced or state.epoch != state.mirror.epoch:
            return state.epoch, []
        with self._queue_lock:
            room = self.config.max_queued // 2 - len(self.queue)
        ids = state.catch_up.next_request(set(state.mirror.poses), now, room=max(room, 0))
        return state.epoch, ids

    def catch_up_answered(self, agent: str, summaries: list[KeyframeSummary], unknown: list[int], now: float) -> int:
        """A catch-up request to ``agent`` was answered: the summaries asked for (and of its current run) are queued
        like the stream's; returns how many. ``unknown``: ids the peer no longer keeps."""
        state = self.peer(agent)
        asked = set(state.catch_up.in_flight)
        taken = [s for s in summaries if s.agent == agent and s.keyframe_id in asked and s.epoch in (0, state.epoch)]
        for summary in taken:
            self.queue_summary(summary, by_catch_up=True)
        state.catch_up.answered([s.keyframe_id for s in taken], unknown, now)
        return len(taken)

    def catch_up_failed(self, agent: str, now: float) -> None:
        """A catch-up request to ``agent`` failed (timed out: the link may be down); asked again later."""
        self.peer(agent).catch_up.failed(now)

    def receive_shared(self, closure: SharedClosure) -> None:
        """A closure a peer verified with this agent (of this agent's current run), used at the next :meth:`step`."""
        self._observe_epoch(closure.peer, closure.epoch)
        with self._queue_lock:
            self.shared.append(closure)

    def _take_shared(self, own_camera_poses: Mapping[int, Pose]) -> int:
        """Add the shared closures whose keyframes are known on both sides; the others wait (bounded)."""
        with self._queue_lock:
            pending = list(self.shared)
            self.shared.clear()
        added, waiting = 0, []
        for closure in pending:
            state = self.peer(closure.peer)
            if closure.epoch != state.epoch:
                continue
            peer_pose = state.mirror.poses.get(closure.peer_id)
            own_pose = own_camera_poses.get(closure.own_id)
            if peer_pose is None or own_pose is None:
                waiting.append(closure)
                continue
            if state.closures.add(
                PairClosure(closure.own_id, closure.peer_id, np.asarray(own_pose), peer_pose, invert(closure.relative))
            ):
                added += 1
                state.decision = state.closures.decide()
        with self._queue_lock:
            self.shared.extendleft(reversed(waiting))
        return added

    def step(self, recognizer: PeerPlaceRecognizer | None, own_camera_poses: Mapping[int, Pose]) -> list[PeerMatch]:
        """Take the closures peers shared, then recognise queued peer keyframes until the queue is empty or the
        budget is spent (not without a ``recognizer``); returns the matches verified here (each also added to its
        peer's closures, whose decision is updated)."""
        start = self.clock()
        matches: list[PeerMatch] = []
        self._take_shared(own_camera_poses)
        if recognizer is None:
            return matches
        while (self.clock() - start) * 1000.0 < self.config.budget_ms:
            with self._queue_lock:
                if not self.queue:
                    break
                summary = self.queue.popleft()
            state = self.peer(summary.agent)
            if summary.epoch not in (0, state.epoch):
                continue  # from a run of the peer that has since restarted (0: a sender that does not say)
            state.recognised += 1
            result = recognizer.recognize(summary)
            match = result.match
            if match is None or match.own_id not in own_camera_poses:
                continue
            peer_pose = state.mirror.poses.get(summary.keyframe_id, summary.pose)
            state.closures.add(
                PairClosure(match.own_id, match.peer_id, np.asarray(own_camera_poses[match.own_id]), peer_pose,
                            match.relative)
            )  # fmt: skip
            state.matches += 1
            state.decision = state.closures.decide()
            matches.append(match)
        return matches

    def alignment(self, peer: str) -> Pose | None:
        """``T_ownmap_peermap`` once the closures with ``peer`` agree (see :class:`ClosureSet`), else None."""
        state = self.peers.get(peer)
        if state is None or state.decision is None:
            return None
        return state.decision.alignment

    def fleet_transform(self, reference: str, peers_in_fleet: Mapping[str, Pose]) -> Pose | None:
        """``T_fleet_ownmap``: identity for the reference agent; else through the first aligned peer (sorted by
        name) whose ``T_fleet_peermap`` is known; None while there is none."""
        if self.agent == reference:
            return np.eye(4)
        for peer in sorted(peers_in_fleet):
            alignment = self.alignment(peer)
            if alignment is not None:
                return np.asarray(peers_in_fleet[peer] @ invert(alignment), dtype=np.float64)
        return None
