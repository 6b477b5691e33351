"""The operator console's pure logic: incremental voxel updates, the teleoperation gate, browser messages.

Browser ⇄ server messages are JSON objects with a ``type``:

server → browser
  ``hello`` {agents, limits}; ``agents`` {agents}; ``voxels`` {agent, size, add [[x,y,z]…], remove […], total};
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
browser → server
  ``ping`` {t}; ``select`` {agent}; ``camera`` {kind}; ``drive`` {agent, v, w, deadman};
  ``estop`` {agent, engage}; ``finding_pick`` {agent, stamp, u, v}; ``finding_create`` {pick, title, severity,
  note}; ``finding_update`` {id, title?, severity?, status?, note?}; ``finding_photo`` {id}; ``measure_pick``
  {agent, stamp, u, v}
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


class VoxelDiff:
    """Keeps the voxels already sent to browsers; turns each new cloud into added and removed voxels.

    Voxels are identified by their centre quantised to ``resolution`` so float noise never re-sends them.
    """

    def __init__(self, resolution: float) -> None:
        self.resolution = resolution
        self._keys: set[tuple[int, int, int]] = set()

    def _quantise(self, points: NDArray[np.float64]) -> set[tuple[int, int, int]]:
        if points.size == 0:
            return set()
        keys = np.floor(np.asarray(points, dtype=np.float64) / self.resolution).astype(np.int64)
        return set(map(tuple, keys.tolist()))  # type: ignore[arg-type]

    def update(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(added centres, removed centres)`` relative to the previous cloud."""
        keys = self._quantise(points)
        added, removed = keys - self._keys, self._keys - keys
        self._keys = keys
        return self._centres(added), self._centres(removed)

    def snapshot(self) -> NDArray[np.float64]:
        """Every voxel currently known (for a browser that connects later)."""
        return self._centres(self._keys)

    def _centres(self, keys: set[tuple[int, int, int]]) -> NDArray[np.float64]:
        if not keys:
            return np.zeros((0, 3))
        return (np.array(sorted(keys), dtype=np.float64) + 0.5) * self.resolution

    def __len__(self) -> int:
        return len(self._keys)


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
