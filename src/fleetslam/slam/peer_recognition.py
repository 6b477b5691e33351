"""Inter-agent loop closure: a peer agent's keyframe recognised in this agent's own memory, and verified geometrically.

A peer's :class:`~fleetslam.fusion.keyframe_summary.KeyframeSummary` is quantised with this agent's own
vocabulary (without adding words: a peer's view must not grow our dictionary) and scored by TF-IDF against the
locations in RAM (short-term and working memory), as the agent's own loop closure scores a new keyframe. The best
few candidates, within a budget, are verified as the agent verifies its own loops: descriptor matches, PnP RANSAC
from the candidate's 3D points into the peer's image and back the other way, the two directions agreeing; and,
unlike its own loops, with enough inliers off the plane that holds most of them (:data:`MIN_OFF_PLANE_INLIERS`:
a tiled floor admits solutions shifted by its period). The transform is full 6-DoF between the two cameras (the
peer's mounting is not known here); it is then refined with the peer's measured depths and believed only when
precise (:func:`refine_closure`: inliers spread over the image, a tight covariance, which the match carries).
The peer's keypoints are first expressed in this camera's pixels (``K_own · K_peer⁻¹``, exact for undistorted
pinhole cameras), so robots with different cameras recognise each other.

Pure: the caller owns the memory and calls :meth:`PeerPlaceRecognizer.recognize` from the thread that updates it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.fusion.keyframe_summary import KeyframeSummary
from fleetslam.geometry import invert
from fleetslam.slam.loop_closure import GeometricVerifier
from fleetslam.slam.loop_config import LoopClosureConfig
from fleetslam.slam.memory import Memory
from fleetslam.slam.pose_refinement import refine_pose_information
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
    covariance: NDArray[np.float64] | None = None
    """6×6 covariance of ``relative`` (translation first, then rotation; a perturbation on the right:
    ``relative · exp(ξ)``) from the refinement (:func:`refine_closure`), scaled as measured; None: not refined."""
    spread: float = 0.0
    """The refined inliers' spread over the image (:func:`image_spread`)."""


def closure_information(match: PeerMatch) -> NDArray[np.float64]:
    """The 36 numbers of ``GraphConstraint.information`` for a peer closure: its covariance's inverse (translation
    first), or zeros when it has none (the fleet back-end then uses its own ``closure_sigma``)."""
    if match.covariance is None:
        return np.zeros(36)
    try:
        information = np.linalg.inv(match.covariance)
    except np.linalg.LinAlgError:
        return np.zeros(36)
    return np.asarray(0.5 * (information + information.T), np.float64).reshape(36)


@dataclass(frozen=True)
class RecognitionResult:
    """What one peer keyframe gave: the verified match (if any) and what was tried."""

    match: PeerMatch | None
    candidates: list[tuple[int, float]]
    """(own location id, score) verified, best first."""
    reasons: list[str]
    """Why each candidate was rejected (or "accepted")."""


@dataclass(frozen=True)
class ClosureQuality:
    """What a peer closure must show, after both-ways PnP, to be believed precise (see :func:`refine_closure`).

    Measured on the collaborative benchmark's verified closures (procedural plant, 320×240; docs/collaboration.md,
    "Precise closures"): of the ten more than 10 cm or 2° off, eight had their inliers bunched in one small patch of
    the image 3–4 m away (spread 0.03–0.06, see :func:`image_spread`), still 5–11 cm off once refined; two were PnP
    leaving the range of far points loose, 1.6 and 5.8 cm off once refined with depth."""

    min_spread: float = 0.07
    """Inliers' standard deviation of pixel position, in each image direction, over the image's size there (a
    uniform spread over the whole image is 0.29): a patch of points far away pins the transform poorly, and a pair
    of stray points off the patch steers it."""
    max_translation_std: float = 0.05
    """Largest standard deviation (m) of the closure's translation (the covariance's largest axis). The precise
    closures of the benchmark had 1–2.3 cm, those of the integration tests' textured room 1.4–4.8 cm (real errors
    under 1 cm): a bound for a closure the solve itself cannot pin, not a filter of the imprecise ones (the spread
    is)."""
    max_rotation_std_deg: float = 1.5
    """Largest standard deviation (degrees) of its rotation."""
    covariance_scale: float = 2.0
    """The solve's covariance times this: its points' errors are correlated (depth quantisation, keypoints at
    edges), so the errors measured against the ground truth were 1.4 times the solve's σ (their squared Mahalanobis
    distance had a median of 10 instead of χ²₆'s 5.3; 4.4–5.1 once scaled)."""
    min_kept_fraction: float = 0.75
    """The refinement must keep this fraction of the verification's minimum inlier count."""
    outlier_sigma: float = 3.4
    """An inlier whose (u, v, depth) residual under the refined transform exceeds this many σ is dropped and the
    refinement repeated (√χ²₃ at 99 %)."""
    depth_noise: float = 1.5e-3
    """σ(z) = depth_noise·z² + 1 mm of the measured depths (the SLAM's ``odometry.depth_noise``)."""
    pixel_std: float = 1.0
    """Standard deviation (px) of a keypoint's position."""


@dataclass(frozen=True)
class RefinedClosure:
    """Outcome of :func:`refine_closure`."""

    relative: NDArray[np.float64]
    """``T_candidate_query``, refined."""
    covariance: NDArray[np.float64]
    """See :attr:`PeerMatch.covariance`."""
    inliers: int
    """Correspondences kept by the refinement."""
    spread: float
    """:func:`image_spread` of the kept inliers in the query's image."""
    reason: str
    """"accepted" or why the closure is not precise enough."""


def image_spread(pixels: NDArray[np.float64], size: tuple[float, float]) -> float:
    """The smaller of the pixels' standard deviations along x and y, each over the image's size along it."""
    if len(pixels) < 2:
        return 0.0
    return float(min(np.std(pixels[:, 0]) / size[0], np.std(pixels[:, 1]) / size[1]))


def refine_closure(
    T_candidate_query: NDArray[np.float64],
    candidate_points: NDArray[np.float64],
    query_pixels: NDArray[np.float64],
    query_depths: NDArray[np.float64],
    camera_matrix: NDArray[np.float64],
    quality: ClosureQuality,
    *,
    min_inliers: int,
) -> RefinedClosure:
    """Refine a verified closure on its PnP inliers with the query's measured depths as residuals too (PnP alone
    leaves far points' range loose: closures 10–23 cm off had 2–3 times the error of the depth-refined ones), drop
    the inliers that do not fit the refined transform and refine again, then judge the result: enough inliers, spread
    over the image (:attr:`ClosureQuality.min_spread`) and a covariance within the quality's bounds.

    ``candidate_points`` (N, 3) in the candidate's camera, seen at ``query_pixels`` (N, 2) with ``query_depths`` (N,)
    (NaN or 0: no depth) in the query's camera (``camera_matrix``)."""
    pose = invert(T_candidate_query)  # T_query_candidate: the candidate's points seen from the query
    keep = np.ones(len(candidate_points), bool)
    depths = np.nan_to_num(np.asarray(query_depths, np.float64), nan=0.0)
    sigma_z = quality.depth_noise * depths**2 + 1e-3
    fx, fy, cx, cy = camera_matrix[0, 0], camera_matrix[1, 1], camera_matrix[0, 2], camera_matrix[1, 2]
    hessian, variance_factor = np.zeros((6, 6)), 1.0
    for _ in range(3):
        if keep.sum() < max(min_inliers, 4):
            break
        pose, hessian, variance_factor = refine_pose_information(
            pose, candidate_points[keep], query_pixels[keep], camera_matrix, pixel_std=quality.pixel_std,
            huber_px=2.0 * quality.pixel_std, iterations=10, depth=(depths[keep], quality.depth_noise),
        )  # fmt: skip
        seen = candidate_points @ pose[:3, :3].T + pose[:3, 3]
        z = np.maximum(seen[:, 2], 1e-6)
        residual = np.column_stack([
            (fx * seen[:, 0] / z + cx - query_pixels[:, 0]) / quality.pixel_std,
            (fy * seen[:, 1] / z + cy - query_pixels[:, 1]) / quality.pixel_std,
            np.where(depths > 0, (seen[:, 2] - depths) / sigma_z, 0.0),
        ])  # fmt: skip
        fits = (seen[:, 2] > 1e-6) & (np.linalg.norm(residual, axis=1) <= quality.outlier_sigma)
        if (fits == keep).all():
            break
        keep = fits
    kept = int(keep.sum())
    relative = invert(pose)
    spread = image_spread(query_pixels[keep], (2.0 * cx + 1.0, 2.0 * cy + 1.0))
    # Left perturbation of T_query_candidate = the inverse's right perturbation (negated): the same covariance.
    try:
        covariance = np.asarray(
            np.linalg.inv(hessian) * max(variance_factor, 1.0) * quality.covariance_scale, np.float64
        )
    except np.linalg.LinAlgError:
        covariance = np.full((6, 6), np.inf)
    if kept < max(min_inliers, 4):
        return RefinedClosure(relative, covariance, kept, spread, f"{kept} inliers fit the refined transform")
    if spread < quality.min_spread:
        why = f"inliers bunched: spread {spread:.3f} of the image (< {quality.min_spread})"
        return RefinedClosure(relative, covariance, kept, spread, why)
    std_m = float(np.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3]).max(), 0.0)))
    std_deg = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(covariance[3:, 3:]).max(), 0.0))))
    precise = std_m <= quality.max_translation_std and std_deg <= quality.max_rotation_std_deg
    if not (np.isfinite(covariance).all() and precise):
        return RefinedClosure(
            relative, covariance, kept, spread, f"imprecise: sigma {std_m * 100:.1f} cm, {std_deg:.2f} deg "
            f"(> {quality.max_translation_std * 100:.1f} cm or {quality.max_rotation_std_deg} deg)",
        )  # fmt: skip
    return RefinedClosure(relative, covariance, kept, spread, "accepted")


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
        quality: ClosureQuality | None = None,
    ) -> None:
        """``verifier`` must work in camera frames (``camera_to_base`` identity, no planar mounting) with this
        agent's camera matrix. ``max_verifications`` bounds the PnP work per peer keyframe;
        ``min_shared_fraction``: a candidate must share at least this fraction of the peer keyframe's words;
        ``quality``: how a verified closure is refined and what it must show (None: not refined, as before)."""
        if not np.allclose(verifier.base_camera, np.eye(4)) or verifier.planar_mounting is not None:
            raise ValueError("the peer verifier works between camera frames: no base mounting, no planar motion")
        self.memory = memory
        self.verifier = verifier
        self.max_verifications = max_verifications
        self.min_shared_fraction = min_shared_fraction
        self.quality = quality

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
            if result.transform is None:
                reasons.append(f"{location_id}: {result.reason}")
                continue
            relative, covariance, spread = result.transform, None, 0.0
            if self.quality is not None and result.matches is not None:
                q_idx, c_idx = result.matches
                refined = refine_closure(
                    result.transform, candidate.points3d[c_idx].astype(np.float64),
                    query.keypoints[q_idx].astype(np.float64), query.points3d[q_idx, 2].astype(np.float64),
                    self.verifier.camera_matrix, self.quality,
                    min_inliers=math.ceil(self.quality.min_kept_fraction * self.verifier.min_inliers),
                )  # fmt: skip
                reasons.append(f"{location_id}: {refined.reason}")
                if refined.reason != "accepted":
                    continue
                relative, covariance, spread = refined.relative, refined.covariance, refined.spread
            else:
                reasons.append(f"{location_id}: {result.reason}")
            match = PeerMatch(
                location_id, summary.agent, summary.keyframe_id, score, relative, result.inliers, result.off_plane,
                covariance, spread,
            )  # fmt: skip
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
    quality: ClosureQuality | None = ClosureQuality(),
) -> PeerPlaceRecognizer:
    """A recognizer over ``memory`` that verifies as the agent's own loop closure does (reprojection error, both PnP
    directions; its own inlier count, ``loop.peer_min_inliers``), between camera frames, and rejects a match with
    fewer than ``min_off_plane`` inliers off the plane that holds most of them (see :data:`MIN_OFF_PLANE_INLIERS`);
    then refines it with depth and judges its precision (``quality``, see :func:`refine_closure`; None: neither)."""
    verifier = GeometricVerifier(
        camera_matrix,
        None,
        min_inliers=loop.peer_min_inliers,
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
    return PeerPlaceRecognizer(memory, verifier, max_verifications=max_verifications, quality=quality)
