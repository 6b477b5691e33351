"""Alignment of agents' map frames into the fleet frame.

Each agent maps in its own `map` frame (its start pose). The fleet frame `fleet` is the first (reference)
agent's map frame unless configured otherwise. An agent's transform ``T_fleet_map`` comes either from its
known start pose, or from inter-agent loop closures: agent b's keyframe j seen from agent a's keyframe i
with relative pose ``T_i_j`` gives ``T_fleet_mapb = T_fleet_mapa · T_mapa_i · T_i_j · inv(T_mapb_j)``.
Several closures are combined robustly (the candidate with most support, then a least-squares rigid fit of
the supporting closures' keyframe positions).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import invert, make_pose, rotation_angle, translation_distance

Pose = NDArray[np.float64]


@dataclass(frozen=True)
class InterAgentClosure:
    """Keyframe ``to_id`` of agent ``to_agent`` seen from keyframe ``from_id`` of ``from_agent``."""

    from_agent: str
    from_id: int
    to_agent: str
    to_id: int
    relative: Pose
    """Pose of the `to` keyframe in the `from` keyframe's frame."""


def candidate_transform(closure: InterAgentClosure, pose_from: Pose, pose_to: Pose, t_fleet_from: Pose) -> Pose:
    """``T_fleet_map(to_agent)`` implied by one closure, given both keyframes' poses in their own map frames."""
    return np.asarray(t_fleet_from @ pose_from @ closure.relative @ invert(pose_to), dtype=np.float64)


def rigid_fit(source: NDArray[np.float64], target: NDArray[np.float64]) -> Pose:
    """Least-squares rigid transform (Kabsch/Umeyama without scale) with ``target ≈ T · source``."""
    if source.shape != target.shape or source.shape[0] < 3:
        raise ValueError(f"rigid_fit needs two (N>=3, 3) arrays of equal shape, got {source.shape}, {target.shape}")
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    cov = (target - mu_t).T @ (source - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, d]) @ vt
    return make_pose(rotation, mu_t - rotation @ mu_s)


def estimate_agent_transform(
    closures: Sequence[InterAgentClosure],
    keyframe_poses: Mapping[str, Mapping[int, Pose]],
    known: Mapping[str, Pose],
    agent: str,
    *,
    inlier_translation_m: float = 0.3,
    inlier_rotation_rad: float = 0.1,
    min_support: int = 1,
) -> tuple[Pose, int] | None:
    """Robust ``T_fleet_map`` of ``agent`` from closures linking it to agents whose transform is ``known``.

    Returns the transform and the number of supporting closures, or None when no candidate has
    ``min_support`` supporters. Closures are used in both directions.
    """
    candidates: list[Pose] = []
    for closure in closures:
        if closure.to_agent == agent and closure.from_agent in known:
            oriented = closure
        elif closure.from_agent == agent and closure.to_agent in known:
            oriented = InterAgentClosure(
                closure.to_agent, closure.to_id, closure.from_agent, closure.from_id, invert(closure.relative)
            )
        else:
            continue
        poses_from = keyframe_poses.get(oriented.from_agent, {})
        poses_to = keyframe_poses.get(oriented.to_agent, {})
        if oriented.from_id not in poses_from or oriented.to_id not in poses_to:
            continue
        candidates.append(
            candidate_transform(
                oriented, poses_from[oriented.from_id], poses_to[oriented.to_id], known[oriented.from_agent]
            )
        )
    if not candidates:
        return None

    def agree(a: Pose, b: Pose) -> bool:
        return (
            translation_distance(a, b) <= inlier_translation_m and rotation_angle(invert(a) @ b) <= inlier_rotation_rad
        )

    support = [[j for j, other in enumerate(candidates) if agree(c, other)] for c in candidates]
    best = max(range(len(candidates)), key=lambda i: len(support[i]))
    inliers = support[best]
    if len(inliers) < min_support:
        return None
    if len(inliers) == 1:
        return candidates[best], 1
    # Average the supporting candidates: fit the transform that maps a few probe points consistently.
    probes = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    source = np.vstack([probes for _ in inliers])
    target = np.vstack([probes @ candidates[i][:3, :3].T + candidates[i][:3, 3] for i in inliers])
    return rigid_fit(source, target), len(inliers)
