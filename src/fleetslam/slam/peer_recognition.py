"""Inter-agent loop closure: a peer agent's keyframe recognised in this agent's own memory, and verified geometrically.

A peer's :class:`~fleetslam.fusion.keyframe_summary.KeyframeSummary` is quantised with this agent's own
vocabulary (without adding words: a peer's view must not grow our dictionary) and scored by TF-IDF against the
locations in RAM (short-term and working memory), as the agent's own loop closure scores a new keyframe. The best
few candidates, within a budget, are verified as the agent verifies its own loops: descriptor matches, PnP RANSAC
from the candidate's 3D points into the peer's image and back the other way, the two directions agreeing; and,
unlike its own loops, with enough inliers off the plane that holds most of them (:data:`MIN_OFF_PLANE_INLIERS`:
a tiled floor admits solutions shifted by its period). The transform is full 6-DoF between the two cameras (the
peer's mounting is not known here). The peer's keypoints are first expressed in this camera's pixels
(``K_own · K_peer⁻¹``, exact for undistorted pinhole cameras), so robots with different cameras recognise each
other.

Pure: the caller owns the memory and calls :meth:`PeerPlaceRecognizer.recognize` from the thread that updates it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.fusion.keyframe_summary import KeyframeSummary
from fleetslam.slam.loop_closure import GeometricVerifier
from fleetslam.slam.loop_config import LoopClosureConfig
from fleetslam.slam.memory import Memory
from fleetslam.slam.signature import Signature

MIN_OFF_PLANE_INLIERS = 8
"""Inliers of a peer match that must lie off the plane holding most of them (5 cm away or more). A plane with a
periodic texture (floor tiles) gives PnP solutions shifted by whole periods that both directions confirm alike, and
several such closures agree with each other, so pairwise consistency cannot reject them either; points off that
plane (shelves, walls, posts) pin the shift. A match on one plane only is dropped, right or wrong: the agents wait
for a view with depth. (An agent's own loops keep a prior from odometry and are not checked this way.)"""


@dataclass(frozen=True)
class PeerMatch:
    """A peer keyframe verified against one of this agent's locations."""

    own_id: int
    peer_agent: str
    peer_id: int
    score: float
    """TF-IDF similarity that made it a candidate."""
    relative: NDArray[np.float64]
    """``T_owncamera_peercamera``."""
    inliers: int
    off_plane: int = 0
    """Inliers off the plane that holds most of them (the floor, often)."""


@dataclass(frozen=True)
class RecognitionResult:
    """What one peer keyframe gave: the verified match (if any) and what was tried."""

    match: PeerMatch | None
    candidates: list[tuple[int, float]]
    """(own location id, score) verified, best first."""
    reasons: list[str]
    """Why each candidate was rejected (or "accepted")."""


def tf_idf_scores(memory: Memory, word_ids: NDArray[np.int64]) -> dict[int, float]:
    """Similarity of a bag of words with every location in RAM that shares a word:
    ``Σ_w (n_wi / n_i) · log10(N / n_w)`` over the query's words, as :meth:`Memory.likelihood`, but over STM
    and WM both (a peer may be looking at what this agent saw a moment ago)."""
    in_ram = len(memory.stm) + len(memory.wm)
    if in_ram == 0:
        return {}
    scores: dict[int, float] = {}
    word_counts: dict[int, int] = {}
    words, _ = np.unique(word_ids[word_ids >= 0], return_counts=True)
    for word in words:
        refs = memory.vocabulary.references(int(word))
        if not refs:
            continue
        idf = math.log10(in_ram / len(refs))
        if idf <= 0.0:
            continue
        for location_id, occurrences in refs.items():
            if location_id not in word_counts:
                signature = memory.signatures.get(location_id)
                word_counts[location_id] = signature.word_count if signature is not None else 0
            if word_counts[location_id] > 0:
                scores[location_id] = scores.get(location_id, 0.0) + occurrences / word_counts[location_id] * idf
    return scores


class PeerPlaceRecognizer:
    """Candidates for a peer keyframe from this agent's memory, verified geometrically, within a budget."""

    def __init__(
        self,
        memory: Memory,
        verifier: GeometricVerifier,
        *,
        max_verifications: int = 2,
        min_shared_fraction: float = 0.05,
    ) -> None:
        """``verifier`` must work in camera frames (``camera_to_base`` identity, no planar mounting) with this
        agent's camera matrix. ``max_verifications`` bounds the PnP work per peer keyframe;
        ``min_shared_fraction``: a candidate must share at least this fraction of the peer keyframe's words."""
        if not np.allclose(verifier.base_camera, np.eye(4)) or verifier.planar_mounting is not None:
            raise ValueError("the peer verifier works between camera frames: no base mounting, no planar motion")
        self.memory = memory
        self.verifier = verifier
        self.max_verifications = max_verifications
        self.min_shared_fraction = min_shared_fraction

    def signature(self, summary: KeyframeSummary) -> Signature:
        """The peer keyframe as a location of this agent (words from this agent's vocabulary, keypoints in this
        agent's pixels); not added to memory."""
        own_k = self.verifier.camera_matrix
        peer = summary.intrinsics
        normalised = np.column_stack(
            [(summary.keypoints[:, 0] - peer.cx) / peer.fx, (summary.keypoints[:, 1] - peer.cy) / peer.fy]
        )
        keypoints = normalised * np.array([own_k[0, 0], own_k[1, 1]]) + own_k[:2, 2]
        word_ids = (
            self.memory.vocabulary.quantize(summary.descriptors, add=False)
            if len(summary) and self.memory.vocabulary.num_active
            else np.full(len(summary), -1, dtype=np.int64)
        )
        return Signature(
            id=-1,
            stamp=summary.stamp_ns / 1e9,
            pose=np.eye(4),
            keypoints=keypoints.astype(np.float32),
            points3d=summary.points3d,
            descriptors=summary.descriptors,
            word_ids=word_ids,
        )

    def recognize(self, summary: KeyframeSummary) -> RecognitionResult:
        """Score the peer keyframe against memory, verify the best candidates, return the first that passes."""
        query = self.signature(summary)
        words = int(np.count_nonzero(np.unique(query.word_ids) >= 0))
        if words == 0:
            return RecognitionResult(None, [], ["no word of the peer keyframe is in this agent's vocabulary"])
        scores = tf_idf_scores(self.memory, query.word_ids)
        shared_needed = max(1, math.ceil(self.min_shared_fraction * words))
        ranked = sorted(scores.items(), key=lambda item: (-item[1], item[0]))
        tried: list[tuple[int, float]] = []
        reasons: list[str] = []
        query_words = set(query.word_ids[query.word_ids >= 0].tolist())
        for location_id, score in ranked:
            if len(tried) >= self.max_verifications:
                break
            candidate = self.memory.signatures[location_id]
            shared = len(query_words & set(candidate.word_ids[candidate.word_ids >= 0].tolist()))
            if shared < shared_needed:
                continue
            tried.append((location_id, score))
            result = self.verifier.verify(query, candidate)
            reasons.append(f"{location_id}: {result.reason}")
            if result.transform is not None:
                match = PeerMatch(
                    location_id,
                    summary.agent,
                    summary.keyframe_id,
                    score,
                    result.transform,
                    result.inliers,
                    result.off_plane,
                )
                return RecognitionResult(match, tried, reasons)
        if not tried:
            reasons.append(f"no location shares {shared_needed} of the peer keyframe's {words} words")
        return RecognitionResult(None, tried, reasons)


def make_peer_recognizer(
    loop: LoopClosureConfig,
    memory: Memory,
    camera_matrix: NDArray[np.float64],
    *,
    max_verifications: int = 2,
    min_off_plane: int = MIN_OFF_PLANE_INLIERS,
) -> PeerPlaceRecognizer:
    """A recognizer over ``memory`` that verifies as the agent's own loop closure does (same inlier count,
    reprojection error, both PnP directions), between camera frames, and rejects a match with fewer than
    ``min_off_plane`` inliers off the plane that holds most of them (see :data:`MIN_OFF_PLANE_INLIERS`)."""
    verifier = GeometricVerifier(
        camera_matrix,
        None,
        min_inliers=loop.min_inliers,
        reprojection_error=loop.pnp_reprojection_error,
        iterations=loop.pnp_iterations,
        max_depth=loop.pnp_max_depth,
        correspondences="descriptors",
        nndr_ratio=loop.nndr_ratio,
        max_disagreement=(
            (loop.max_direction_disagreement, float(np.radians(loop.max_direction_disagreement_deg)))
            if loop.max_direction_disagreement > 0
            else (0.05, float(np.radians(2.0)))
        ),
        min_off_plane=min_off_plane,
    )
    return PeerPlaceRecognizer(memory, verifier, max_verifications=max_verifications)
