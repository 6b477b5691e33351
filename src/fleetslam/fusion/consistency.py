"""Which inter-agent loop closures to believe: pairwise consistency and the largest consistent set (PCM).

Two agents map in frames that nothing relates until they recognise a shared place. Each verified closure
(keyframe ``i`` of agent a sees keyframe ``j`` of agent b at ``T_i_j``) implies where b's map frame lies in a's:
``T_mapa_mapb = T_mapa_i · T_i_j · T_mapb_j⁻¹``. Closures on the same place agree on it; a closure on repeated
structure (the next shelf, the same tiles) implies a frame shifted by the pattern's period. Following Pairwise
Consistency Maximisation (Mangelson et al., ICRA 2018), two closures are consistent when each one's implied frame
puts the other's keyframes where the other says they are, within a tolerance that grows with the distance between
the two places (the agents' own drift between them); the closures to believe are the largest mutually consistent
set (a maximum clique of the consistency graph).

Repeated structure along an aisle can itself form a consistent set (every keyframe matched one module further on),
so a set is accepted only when it is large enough, spans more than one place, and clearly outnumbers any set
inconsistent with it (:meth:`ClosureSet.decide`); otherwise the agents wait for a place that tells them apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.fusion.alignment import rigid_fit
from fleetslam.geometry import invert, rotation_angle

Pose = NDArray[np.float64]

_PROBES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
"""A keyframe's position and points one metre along its axes: fitting a frame to these weighs rotation and
translation as they act at the keyframe, not at the far-away map origin."""


@dataclass(frozen=True)
class PairClosure:
    """Keyframe ``peer_id`` of the peer seen from keyframe ``own_id`` of this agent (camera frames)."""

    own_id: int
    peer_id: int
    own_pose: Pose
    """``T_ownmap_owncamera`` of keyframe ``own_id``."""
    peer_pose: Pose
    """``T_peermap_peercamera`` of keyframe ``peer_id``."""
    relative: Pose
    """``T_owncamera_peercamera``: the verified closure."""

    @property
    def implied(self) -> Pose:
        """``T_ownmap_peermap`` this closure implies."""
        return np.asarray(self.own_pose @ self.relative @ invert(self.peer_pose), dtype=np.float64)


@dataclass(frozen=True)
class ConsistencyTolerance:
    """How far two closures' implied frames may disagree and still be believed together."""

    translation_m: float = 0.15
    """Disagreement allowed between closures on (nearly) the same place: verification noise."""
    rotation_rad: float = float(np.radians(3.0))
    drift_fraction: float = 0.05
    """Extra translation allowed per metre between the two places (both agents' odometry drift)."""
    drift_rad_per_m: float = float(np.radians(0.5))
    """Extra rotation allowed per metre between the two places."""


def consistent(a: PairClosure, b: PairClosure, tolerance: ConsistencyTolerance) -> bool:
    """Whether the two closures can both be right: ``a``'s implied frame puts ``b``'s peer keyframe where ``b``
    puts it (and the other way), and their implied rotations agree, within the distance-scaled tolerance."""
    implied_a, implied_b = a.implied, b.implied
    at_a = a.own_pose[:3, 3]
    at_b = b.own_pose[:3, 3]
    span = float(np.linalg.norm(at_a - at_b)) + float(np.linalg.norm(a.peer_pose[:3, 3] - b.peer_pose[:3, 3]))
    allowed_m = tolerance.translation_m + tolerance.drift_fraction * span
    allowed_rad = tolerance.rotation_rad + tolerance.drift_rad_per_m * span
    for closure in (a, b):
        peer_position = np.append(closure.peer_pose[:3, 3], 1.0)
        if np.linalg.norm((implied_a @ peer_position - implied_b @ peer_position)[:3]) > allowed_m:
            return False
    return rotation_angle(invert(implied_a) @ implied_b) <= allowed_rad


def maximum_clique(adjacency: Sequence[set[int]], among: set[int] | None = None) -> list[int]:
    """A largest set of mutually adjacent vertices (Bron–Kerbosch with pivoting); ties go to lower indices."""
    vertices = set(range(len(adjacency))) if among is None else set(among)
    best: list[int] = []

    def expand(clique: list[int], candidates: set[int], excluded: set[int]) -> None:
        nonlocal best
        if not candidates and not excluded:
            if len(clique) > len(best) or (len(clique) == len(best) and sorted(clique) < sorted(best)):
                best = sorted(clique)
            return
        if len(clique) + len(candidates) < len(best):
            return
        pivot = max(candidates | excluded, key=lambda v: len(adjacency[v] & candidates))
        for vertex in sorted(candidates - adjacency[pivot]):
            expand([*clique, vertex], candidates & adjacency[vertex], excluded & adjacency[vertex])
            candidates = candidates - {vertex}
            excluded = excluded | {vertex}

    expand([], vertices, set())
    return best


def fit_frames(source: Sequence[Pose] | NDArray[np.float64], target: Sequence[Pose] | NDArray[np.float64]) -> Pose:
    """``T`` with ``target[k] ≈ T · source[k]`` for every pair of poses, in the least-squares sense over each pose's
    position and axes (one pair is enough)."""
    if len(source) != len(target) or not len(source):
        raise ValueError(f"fit_frames needs two equally long, non-empty lists of poses: {len(source)}, {len(target)}")
    return rigid_fit(_probes(source), _probes(target))


def _probes(poses: Sequence[Pose] | NDArray[np.float64]) -> NDArray[np.float64]:
    """The :data:`_PROBES` of every pose (a sequence or a stack of 4×4 poses), as one (4·N, 3) array."""
    stack = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    return (np.einsum("pj,nij->npi", _PROBES, stack[:, :3, :3]) + stack[:, None, :3, 3]).reshape(-1, 3)


def fit_alignment(closures: Sequence[PairClosure]) -> Pose:
    """``T_ownmap_peermap`` that best agrees with all the closures (least squares over each closure's keyframe
    position and axes)."""
    if not closures:
        raise ValueError("fit_alignment needs at least one closure")
    return fit_frames([c.peer_pose for c in closures], [c.own_pose @ c.relative for c in closures])


@dataclass(frozen=True)
class Decision:
    """Outcome of :meth:`ClosureSet.decide`."""

    alignment: Pose | None
    """``T_ownmap_peermap`` when accepted."""
    inliers: list[int]
    """Indices of the closures believed (the largest consistent set), accepted or not."""
    rival: int
    """Size of the largest set inconsistent with the inliers (repeated structure shows up here)."""
    reason: str


@dataclass
class ClosureSet:
    """The verified closures between this agent and one peer, and whether they agree enough to align the maps."""

    tolerance: ConsistencyTolerance = field(default_factory=ConsistencyTolerance)
    min_inliers: int = 3
    """Closures in the consistent set before the maps are aligned."""
    min_places: int = 2
    """Places among the inliers' own keyframes, counted ``place_spacing_m`` apart: one place seen several times is
    one piece of evidence."""
    place_spacing_m: float = 0.5
    places_either_side: bool = False
    """Count the places on the peer's keyframes too, and take the larger count: for a judge of both agents' closures
    (the fleet back-end), which connects a pair when either agent's own test would."""
    dominance: float = 2.0
    """The consistent set must be this many times larger than the largest set inconsistent with it."""
    max_closures: int = 64
    """Closures kept (the oldest leave first): bounds the clique search."""
    closures: list[PairClosure] = field(default_factory=list)
    _adjacency: list[set[int]] = field(default_factory=list)

    def add(self, closure: PairClosure) -> bool:
        """Add a verified closure (the oldest is dropped beyond ``max_closures``); False when the same pair of
        keyframes is there already (both agents may verify it: it is one piece of evidence)."""
        if any(c.own_id == closure.own_id and c.peer_id == closure.peer_id for c in self.closures):
            return False
        if len(self.closures) >= self.max_closures:
            self.closures.pop(0)
            self._adjacency = [{j - 1 for j in row if j > 0} for row in self._adjacency[1:]]
        index = len(self.closures)
        row = {j for j, other in enumerate(self.closures) if consistent(closure, other, self.tolerance)}
        for j in row:
            self._adjacency[j].add(index)
        self.closures.append(closure)
        self._adjacency.append(row)
        return True

    def decide(self) -> Decision:
        """The largest consistent set, and the alignment it gives when it is large, spread and unrivalled."""
        inliers = maximum_clique(self._adjacency)
        if not inliers:
            return Decision(None, [], 0, "no closures yet")
        # A rival: the largest consistent set among closures that disagree with most of the inliers.
        outsiders = {
            i for i in range(len(self.closures)) if len(self._adjacency[i] & set(inliers)) * 2 < len(inliers)
        } - set(inliers)
        rival = len(maximum_clique(self._adjacency, outsiders)) if outsiders else 0
        places = _distinct_places([self.closures[i].own_pose[:3, 3] for i in inliers], self.place_spacing_m)
        if self.places_either_side:
            places = max(
                places, _distinct_places([self.closures[i].peer_pose[:3, 3] for i in inliers], self.place_spacing_m)
            )
        if len(inliers) < self.min_inliers:
            return Decision(None, inliers, rival, f"{len(inliers)} consistent closures (< {self.min_inliers})")
        if places < self.min_places:
            return Decision(None, inliers, rival, f"consistent closures at {places} place(s) (< {self.min_places})")
        if len(inliers) < self.dominance * rival:
            return Decision(
                None, inliers, rival, f"ambiguous: {len(inliers)} consistent closures against a rival set of {rival}"
            )
        alignment = fit_alignment([self.closures[i] for i in inliers])
        return Decision(alignment, inliers, rival, "accepted")


def _distinct_places(positions: Sequence[NDArray[np.float64]], spacing_m: float) -> int:
    """Greedy count of positions at least ``spacing_m`` from every position counted before."""
    kept: list[NDArray[np.float64]] = []
    for position in positions:
        if all(np.linalg.norm(position - other) >= spacing_m for other in kept):
            kept.append(position)
    return len(kept)
