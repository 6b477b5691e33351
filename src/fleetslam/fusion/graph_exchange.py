"""A keyframe graph sent as deltas: new keyframes, moved poses and new constraints, with a sequence number.

The whole graph of an agent grows with the run (tens of kB after a few minutes) and re-sending it on every
change costs each reader that much per update. :class:`GraphDeltaWriter` remembers what it last sent and gives
only what changed: keyframes not sent before, keyframes whose pose moved more than a threshold (after a loop
closure that can be most of them: the optimisation moves everything, once), and constraints added since. Each
update carries a sequence number; :class:`GraphMirror` applies them in order and, when one is missing (a link
that dropped messages, a reader that joined late), says so: the reader then asks for the full graph (a service),
which the writer builds on request without disturbing the stream.

A writer's ``epoch`` (random, one per SLAM run) tells a restarted agent from one that only skipped numbers: a
reader seeing a new epoch drops what it had of that agent, whose map frame is a new one.

Pure: no middleware. Poses are 4×4 ``T_map_camera``; constraints are opaque values the caller defines (compared by
identity of their position in the list the writer is given).
"""

from __future__ import annotations

import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import MessageError
from fleetslam.geometry import invert, rotation_angle

Pose = NDArray[np.float64]
ConstraintT = TypeVar("ConstraintT")


@dataclass(frozen=True)
class GraphUpdate(Generic[ConstraintT]):
    """One message's worth of a keyframe graph."""

    sequence: int
    """1 for the first update of a writer, then consecutive; a full graph carries the writer's current number."""
    full: bool
    """The whole graph (replaces what a reader has) rather than the changes since ``sequence - 1``."""
    poses: dict[int, Pose]
    """Keyframe id -> pose: new keyframes and moved ones (every keyframe when ``full``)."""
    stamps: dict[int, float]
    """Keyframe id -> stamp (s) of the keyframes in ``poses``."""
    constraints: list[ConstraintT]
    """Constraints added since the previous update (every constraint when ``full``)."""
    epoch: int = 0
    """The writer's run (see the module docstring)."""

    def __bool__(self) -> bool:
        return bool(self.poses or self.constraints or self.full)


@dataclass
class GraphDeltaWriter(Generic[ConstraintT]):
    """What changed in a keyframe graph since the last update sent."""

    translation_m: float = 0.002
    """A keyframe whose pose moved less than this (and ``rotation_rad``) since last sent is not sent again."""
    rotation_rad: float = 0.002
    sequence: int = 0
    epoch: int = field(default_factory=lambda: secrets.randbits(63) + 1)
    """This writer's run: random, so that a restarted agent is told from a running one."""
    _sent_poses: dict[int, Pose] = field(default_factory=dict)
    _sent_constraints: int = 0

    @property
    def sent_keyframes(self) -> int:
        """Keyframes the updates sent so far hold."""
        return len(self._sent_poses)

    def update(
        self,
        poses: Mapping[int, Pose],
        stamps: Mapping[int, float],
        constraints: Sequence[ConstraintT],
        *,
        full: bool = False,
    ) -> GraphUpdate[ConstraintT] | None:
        """The next delta, or None when nothing changed. ``constraints`` only grow; if the list is shorter than what
        was sent (constraints retracted), or with ``full`` (the caller's list was rebuilt), the update is a full
        graph."""
        if full or len(constraints) < self._sent_constraints or any(i not in poses for i in self._sent_poses):
            return self._emit(poses, stamps, constraints, full=True)
        changed = {
            i: np.array(pose, dtype=np.float64)
            for i, pose in poses.items()
            if i not in self._sent_poses or self._moved(self._sent_poses[i], pose)
        }
        new_constraints = list(constraints[self._sent_constraints :])
        if not changed and not new_constraints:
            return None
        self.sequence += 1
        self._sent_poses.update(changed)
        self._sent_constraints = len(constraints)
        return GraphUpdate(
            self.sequence, False, changed, {i: float(stamps[i]) for i in changed}, new_constraints, self.epoch
        )

    def full(
        self, poses: Mapping[int, Pose], stamps: Mapping[int, float], constraints: Sequence[ConstraintT]
    ) -> GraphUpdate[ConstraintT]:
        """The whole graph as of the last update sent, for a reader that asked (the stream is not disturbed: its
        next delta still follows the last one sent)."""
        return GraphUpdate(
            self.sequence,
            True,
            {i: np.array(poses[i], dtype=np.float64) for i in self._sent_poses if i in poses},
            {i: float(stamps[i]) for i in self._sent_poses if i in stamps},
            list(constraints[: self._sent_constraints]),
            self.epoch,
        )

    def _emit(
        self, poses: Mapping[int, Pose], stamps: Mapping[int, float], constraints: Sequence[ConstraintT], *, full: bool
    ) -> GraphUpdate[ConstraintT]:
        self.sequence += 1
        self._sent_poses = {i: np.array(p, dtype=np.float64) for i, p in poses.items()}
        self._sent_constraints = len(constraints)
        return GraphUpdate(
            self.sequence,
            full,
            dict(self._sent_poses),
            {i: float(stamps[i]) for i in poses},
            list(constraints),
            self.epoch,
        )

    def _moved(self, sent: Pose, now: Pose) -> bool:
        difference = invert(sent) @ np.asarray(now, dtype=np.float64)
        return bool(
            np.linalg.norm(difference[:3, 3]) > self.translation_m or rotation_angle(difference) > self.rotation_rad
        )


@dataclass
class GraphMirror(Generic[ConstraintT]):
    """A reader's copy of a writer's graph, kept by applying its updates in order."""

    poses: dict[int, Pose] = field(default_factory=dict)
    stamps: dict[int, float] = field(default_factory=dict)
    constraints: list[ConstraintT] = field(default_factory=list)
    sequence: int = 0
    """Sequence of the last update applied (0: none yet)."""
    epoch: int = 0
    """The writer's run the mirror holds (0: none yet)."""
    synced: bool = False
    """Whether the mirror holds the writer's graph as of ``sequence`` (False until a full graph, or the first
    update, arrives; False again after a gap)."""
    max_pending: int = 64
    """Deltas kept while waiting for a full graph (they may follow it); the oldest are dropped beyond this."""
    _pending: dict[int, GraphUpdate[ConstraintT]] = field(default_factory=dict)

    def apply(self, update: GraphUpdate[ConstraintT]) -> bool:
        """Apply an update; False when the mirror is out of sync (a gap before it: ask the writer for the full
        graph). Deltas that arrive while out of sync are kept and applied after the full graph they follow; a full
        graph older than the mirror (answered after newer deltas arrived) is ignored. An update of a new epoch (the
        writer restarted) first empties the mirror."""
        if update.epoch != self.epoch:
            self.poses, self.stamps, self.constraints = {}, {}, []
            self.sequence, self.synced, self.epoch = 0, False, update.epoch
            self._pending.clear()
        if update.full:
            if self.synced and update.sequence < self.sequence:
                return True
            self.poses = dict(update.poses)
            self.stamps = dict(update.stamps)
            self.constraints = list(update.constraints)
            self.sequence = update.sequence
            self.synced = True
            self._drain()
            return self.synced
        if self.synced and update.sequence <= self.sequence:
            return True  # a duplicate, or a delta the full graph already contained
        if (self.synced and update.sequence == self.sequence + 1) or (self.sequence == 0 and update.sequence == 1):
            self._extend(update)
            self._drain()
            return self.synced
        self.synced = False
        self._pending[update.sequence] = update
        while len(self._pending) > self.max_pending:
            del self._pending[min(self._pending)]
        return False

    def _extend(self, update: GraphUpdate[ConstraintT]) -> None:
        self.poses.update(update.poses)
        self.stamps.update(update.stamps)
        self.constraints.extend(update.constraints)
        self.sequence = update.sequence
        self.synced = True

    def _drain(self) -> None:
        """Apply the kept deltas that follow on; forget those the mirror already holds."""
        for sequence in sorted(self._pending):
            if sequence <= self.sequence:
                del self._pending[sequence]
            elif sequence == self.sequence + 1:
                self._extend(self._pending.pop(sequence))
            else:
                self.synced = False
                return


MAX_GRAPH_KEYFRAMES = 1_000_000
"""A received graph with more keyframes (or constraints) than this is refused."""


def graph_update_of(msg: Any) -> GraphUpdate[Any]:
    """A received ``fleetslam_msgs/KeyframeGraph`` as a :class:`GraphUpdate` (poses as 4×4 matrices, stamps in
    seconds); a malformed one raises :class:`MessageError` naming the field."""
    from fleetslam.msg.conversions import pose_matrix

    where = f"KeyframeGraph from {str(msg.agent)!r}"
    poses = []
    for pose in msg.poses:
        try:
            matrix = pose_matrix(pose)
        except ValueError as err:
            raise MessageError(f"{where}: a pose is not a rotation ({err})") from err
        poses.append(matrix)
    stamps = [(int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)) / 1e9 for stamp in msg.stamps]
    return graph_update_from_message(msg, poses, stamps)


def graph_update_from_message(msg: Any, poses: Sequence[Pose], stamps: Sequence[float]) -> GraphUpdate[Any]:
    """A :class:`GraphUpdate` from a received ``fleetslam_msgs/KeyframeGraph`` whose poses and stamps the caller
    converted (``poses[k]``, ``stamps[k]`` of ``msg.keyframe_ids[k]``); its constraints are kept as they came.
    A malformed one raises :class:`MessageError` naming the field."""
    where = f"KeyframeGraph from {str(msg.agent)!r} (sequence {int(msg.sequence)})"
    ids = [int(i) for i in msg.keyframe_ids]
    if len(ids) > MAX_GRAPH_KEYFRAMES or len(msg.constraints) > MAX_GRAPH_KEYFRAMES:
        raise MessageError(f"{where}: {len(ids)} keyframes, {len(msg.constraints)} constraints: too many")
    if len(poses) != len(ids) or len(stamps) != len(ids):
        raise MessageError(f"{where}: {len(ids)} keyframe ids with {len(poses)} poses and {len(stamps)} stamps")
    if len(set(ids)) != len(ids):
        raise MessageError(f"{where}: a keyframe id appears twice")
    for i, pose in zip(ids, poses, strict=True):
        if not np.isfinite(pose).all():
            raise MessageError(f"{where}: the pose of keyframe {i} is not finite")
    if int(msg.sequence) < 1:
        raise MessageError(f"{where}: sequence must be >= 1")
    return GraphUpdate(
        int(msg.sequence),
        bool(msg.full),
        {i: np.asarray(p, dtype=np.float64) for i, p in zip(ids, poses, strict=True)},
        {i: float(t) for i, t in zip(ids, stamps, strict=True)},
        list(msg.constraints),
        int(msg.epoch),
    )


def graph_message(agent: str, update: GraphUpdate[Any], *, frame_id: str = "map", stamp_ns: int = 0,
                  optimized: bool = False) -> Any:  # fmt: skip
    """The ``fleetslam_msgs/KeyframeGraph`` of an update whose constraints are ``GraphConstraint`` messages (the
    inverse of :func:`graph_update_of`)."""
    from fleetslam.msg.conversions import pose_msgs
    from fleetslam.msg.typesys import get_type, header, stamp_from_ns

    ids = sorted(update.poses)
    return get_type("fleetslam_msgs/msg/KeyframeGraph")(
        header=header(frame_id, stamp_ns), agent=agent, keyframe_ids=np.asarray(ids, np.uint32),
        poses=pose_msgs([update.poses[i] for i in ids]),
        stamps=[stamp_from_ns(round(update.stamps.get(i, 0.0) * 1e9)) for i in ids],
        constraints=list(update.constraints), optimized=optimized, sequence=max(update.sequence, 1),
        full=update.full, epoch=update.epoch,
    )  # fmt: skip
