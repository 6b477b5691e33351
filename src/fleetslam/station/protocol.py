"""The operator console's pure logic: incremental voxel updates, the teleoperation gate, browser messages.

Browser ⇄ server messages are JSON objects with a ``type``:

server → browser
  ``hello`` {agents, limits}; ``agents`` {agents}; ``voxels``: a binary message (:meth:`VoxelUpdate.encode`: voxel
  indices added and removed, the deltas merged while the browser was busy);
  ``pose`` {agent, source, x, y, z, yaw, q: [x, y, z, w]} (the robot's base; ``slam``: in its map frame, from the
  camera's pose); ``path`` {agent, source, points}; ``keyframes`` {agent, poses};
  ``image`` {agent, kind: rgb|depth, mime, data (base64), seq, stamp (ns, a decimal string)}; ``stats`` {rows};
  ``pong`` {t};
  ``frame`` {agent, placement: ``T_fleet_map``, mounting: ``T_base_camera`` (4×4 row-major, null until known)}: the
  agent's map, path, keyframes and ``slam`` pose are in its map frame (its camera's at start), placed in the fleet
  frame by ``placement`` (its own frame until then) and drawn upright through ``mounting``;
  ``estop`` {agent, engaged, ok, message}; ``findings`` {findings}; ``finding_pick``,
  ``finding_created``, ``finding_updated``, ``finding_photo``, ``measure_point`` {ok, message, agent, stamp, point
  (map frame), range} (answers, see :mod:`fleetslam.station.findings`)
``/ws?role=link`` is a connection that only answers ``ping`` {t} with ``pong`` {t}: the page's link indicator, judged in
a worker of its own (``static/link.js``) so that a busy page never reads as a lost link.

browser → server
  ``ping`` {t}; ``ack`` {bytes}: how much of the bulk streams (images, voxels, poses, paths, keyframes, statistics:
  text messages count their characters, binary ones their bytes) the page has handled; the server keeps at most
  :data:`fleetslam.station.server.BULK_WINDOW` unacknowledged, keeps only the newest of each stream meanwhile
  (voxels: merged), and sends control messages (pong, replies) first; ``select`` {agent}; ``camera`` {kind};
  ``drive`` {agent, v, w, deadman};
  ``estop`` {agent, engage}; ``finding_pick`` {agent, stamp, u, v}; ``finding_create`` {pick, title, severity,
  note}; ``finding_update`` {id, title?, severity?, status?, note?}; ``finding_photo`` {id}; ``measure_pick``
  {agent, stamp, u, v}
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

KEY_BITS = 21
"""Bits per axis of a packed voxel key: ±2²⁰ voxels (±52 km at 5 cm) each way."""
_KEY_OFFSET = 1 << (KEY_BITS - 1)
_KEY_MASK = (1 << KEY_BITS) - 1


def pack_keys(indices: NDArray[np.int64]) -> NDArray[np.int64]:
    """Voxel indices ``(n, 3)`` as one sortable int64 each."""
    shifted = np.asarray(indices, dtype=np.int64).reshape(-1, 3) + _KEY_OFFSET
    return np.asarray((shifted[:, 0] << (2 * KEY_BITS)) | (shifted[:, 1] << KEY_BITS) | shifted[:, 2], dtype=np.int64)


def unpack_keys(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """Packed keys back to voxel indices ``(n, 3)``."""
    keys = np.asarray(keys, dtype=np.int64)
    return np.stack(
        [(keys >> (2 * KEY_BITS)) & _KEY_MASK, (keys >> KEY_BITS) & _KEY_MASK, keys & _KEY_MASK], axis=1
    ) - (_KEY_OFFSET)


class VoxelDiff:
    """Keeps the voxels already sent to browsers; turns each new cloud into added and removed voxels.

    Voxels are identified by their index (centre quantised to ``resolution``, packed by :func:`pack_keys`) so float
    noise never re-sends them; the browsers get the indices (a voxel's centre is ``(index + 1/2) · resolution``).
    """

    def __init__(self, resolution: float) -> None:
        self.resolution = resolution
        self._keys: NDArray[np.int64] = np.zeros(0, dtype=np.int64)

    def _quantise(self, points: NDArray[np.float64]) -> NDArray[np.int64]:
        if points.size == 0:
            return np.zeros(0, dtype=np.int64)
        indices = np.floor(np.asarray(points, dtype=np.float64).reshape(-1, 3) / self.resolution).astype(np.int64)
        return np.unique(pack_keys(indices))

    def update(self, points: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """``(added keys, removed keys)`` (packed, sorted) relative to the previous cloud."""
        keys = self._quantise(points)
        added = np.setdiff1d(keys, self._keys, assume_unique=True)
        removed = np.setdiff1d(self._keys, keys, assume_unique=True)
        self._keys = keys
        return added, removed

    def keys(self) -> NDArray[np.int64]:
        """Every voxel currently known (packed keys; for a browser that connects later)."""
        return self._keys

    def centres(self, keys: NDArray[np.int64]) -> NDArray[np.float64]:
        """The centres of packed keys."""
        return (unpack_keys(keys).astype(np.float64) + 0.5) * self.resolution

    def __len__(self) -> int:
        return len(self._keys)


@dataclass
class VoxelUpdate:
    """Voxels of one agent's map still to send to one browser: the deltas that arrived while it was busy, merged
    into one (stale deltas are never queued), sent as one binary WebSocket message (:meth:`encode`).

    Invariant of a delta against what the browser has (``have``): ``add`` ∩ have = ∅ and ``remove`` ⊆ have.
    """

    agent: str
    size: float
    add: NDArray[np.int64]
    remove: NDArray[np.int64]
    total: int
    reset: bool = False
    """The browser drops every voxel of the agent first (a new browser's first update)."""

    def merge(self, later: VoxelUpdate) -> None:
        """Follow this update by ``later`` (made against what the browser has after this one)."""
        # A voxel added here and removed later was never sent, and one removed here and added back is still there.
        self.add, self.remove = (
            np.union1d(np.setdiff1d(self.add, later.remove, True), np.setdiff1d(later.add, self.remove, True)),
            np.union1d(np.setdiff1d(self.remove, later.add, True), np.setdiff1d(later.remove, self.add, True)),
        )
        self.size, self.total = later.size, later.total
        self.reset = self.reset or later.reset

    def encode(self) -> bytes:
        """``u32 n`` · ``n`` bytes of JSON {type: "voxels", agent, size, add, remove, total, reset} (counts), padded
        with spaces to 4 bytes · int32 voxel indices (i, j, k) of the added voxels, then of the removed ones; little
        endian. A voxel's centre is ``(index + 1/2) · size``."""
        header = json.dumps(
            {"type": "voxels", "agent": self.agent, "size": self.size, "add": len(self.add),
             "remove": len(self.remove), "total": self.total, "reset": self.reset}
        ).encode()  # fmt: skip
        header += b" " * (-len(header) % 4)
        indices = np.concatenate([unpack_keys(self.add), unpack_keys(self.remove)]).astype("<i4")
        return struct.pack("<I", len(header)) + header + indices.tobytes()


def decode_voxels(data: bytes) -> tuple[dict[str, Any], NDArray[np.int32], NDArray[np.int32]]:
    """A binary voxel message: its header and the indices ``(n, 3)`` added and removed (for tests and programs)."""
    (length,) = struct.unpack_from("<I", data)
    header = json.loads(data[4 : 4 + length])
    indices = np.frombuffer(data, dtype="<i4", offset=4 + length).reshape(-1, 3)
    return header, indices[: header["add"]], indices[header["add"] :]


@dataclass(frozen=True)
class TeleopLimits:
    """Speed limits the console enforces, whatever the browser asks for."""

    max_linear: float = 0.5
    """m/s."""
    max_angular: float = 1.2
    """rad/s."""
    command_timeout_s: float = 0.3
    """A drive message older than this (no refresh from the browser) stops the stream."""


@dataclass
class _DriveState:
    v: float = 0.0
    w: float = 0.0
    deadman: bool = False
    updated: float = -math.inf
    sent_zero: bool = True


@dataclass
class TeleopGate:
    """Decides which Twist commands to send, per agent, on each tick of a fixed-rate stream.

    Commands flow only while the deadman is held and the browser keeps refreshing them; when the deadman is
    released, the browser goes silent or disconnects, exactly one zero command is sent and then nothing, so
    the robot's own watchdog keeps it stopped.
    """

    limits: TeleopLimits = field(default_factory=TeleopLimits)
    _states: dict[str, _DriveState] = field(default_factory=dict)

    def drive(self, agent: str, v: float, w: float, deadman: bool, now: float) -> None:
        state = self._states.setdefault(agent, _DriveState())
        state.v = _clamp(v, self.limits.max_linear)
        state.w = _clamp(w, self.limits.max_angular)
        state.deadman = bool(deadman)
        state.updated = now

    def release(self, agent: str) -> None:
        """The driving browser disconnected: stop at the next tick."""
        state = self._states.get(agent)
        if state is not None:
            state.deadman = False
            state.updated = -math.inf

    def tick(self, now: float) -> dict[str, tuple[float, float]]:
        """Commands to publish now: (v, ω) per agent."""
        out: dict[str, tuple[float, float]] = {}
        for agent, state in self._states.items():
            live = state.deadman and now - state.updated <= self.limits.command_timeout_s
            if live:
                out[agent] = (state.v, state.w)
                state.sent_zero = False
            elif not state.sent_zero:
                out[agent] = (0.0, 0.0)
                state.sent_zero = True
        return out


def _clamp(value: float, limit: float) -> float:
    if not math.isfinite(value):
        return 0.0
    return max(-limit, min(limit, float(value)))


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Heading of a ROS quaternion."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
