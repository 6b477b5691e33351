"""Appearance-based loop-closure detection with geometric verification (RTAB-Map ``Rtabmap::process``).

The pipeline calls :meth:`LoopClosureDetector.process` once per keyframe::

    detector = make_loop_closure_detector(cfg.loop_closure, cfg.memory, camera_matrix, T_base_camera)
    hyp = detector.process(stamp, T_world_base, keypoints_uv, points_cam, descriptors,
                           odometry_transform=T_prev_new, odometry_information=info6x6,
                           rgb_compressed=jpeg_bytes, depth_compressed=png_bytes)
    # hyp.query_id is the new location's id (the pose-graph node id); the odometry link
    # previous -> new is already in detector.memory. If hyp.accepted: add the factor
    # between hyp.match_id and hyp.query_id with hyp.transform (T_match_query) and
    # detector.memory.signatures[hyp.match_id].links[hyp.query_id].information.
    # At the end of the run:  with MapDatabase(out / "map.db") as db: detector.memory.save(db)
    # Next session:           with MapDatabase(path) as db: mem = load_memory(db, cfg.loop_closure, cfg.memory)
    #                         detector = make_loop_closure_detector(..., existing_memory=mem)

Per keyframe: add the location to memory (vocabulary, rehearsal, STM -> WM), score it against the WM
(TF-IDF), normalise the likelihood, update the Bayes filter, take the highest hypothesis (its value is the
sum of the loop-closure probabilities, ``1 - P(new place)``, as RTAB-Map), retrieve its LTM neighbours,
accept it if ``value >= loop_threshold``, it passes the ratio test and PnP RANSAC verification, then
transfer WM -> LTM if over the WM size or the time budget (measured with the injected ``clock``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.errors import MissingExtraError, SlamError
from fleetslam.geometry import invert, make_pose
from fleetslam.slam.bayes_filter import VIRTUAL_PLACE, BayesFilter, adjust_likelihood
from fleetslam.slam.database import MapDatabase
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.memory import Memory
from fleetslam.slam.signature import Link, LinkType, Signature
from fleetslam.slam.vocabulary import VisualVocabulary

logger = logging.getLogger(__name__)

DEFAULT_LOOP_INFORMATION = np.eye(6) * 1e4
"""Information of an accepted loop link: 1 cm / 0.01 rad standard deviation on every axis."""


@dataclass
class VerificationResult:
    """Outcome of :meth:`GeometricVerifier.verify`."""

    transform: NDArray[np.float64] | None
    """``T_candidate_query`` in base frames (pose of the query in the candidate's frame) or None."""
    inliers: int
    """PnP RANSAC inliers (0 when it did not run)."""
    correspondences: int
    """Word correspondences with a valid 3D point fed to PnP."""
    reason: str
    """"accepted" or why it was rejected."""

    @property
    def accepted(self) -> bool:
        """Whether the transform is valid."""
        return self.transform is not None


@dataclass
class LoopHypothesis:
    """Result of one keyframe of loop-closure detection."""

    query_id: int
    """Id of the location just added."""
    match_id: int | None
    """Highest hypothesis (a WM location) or None when there is none."""
    probability: float
    """Hypothesis value: sum of loop-closure probabilities, 1 - P(new place)."""
    accepted: bool
    transform: NDArray[np.float64] | None
    """``T_match_query`` (pose of the query in the match's base frame) when accepted."""
    inliers: int
    reason: str
    """"accepted" or why not."""
    rehearsed_with: int | None = None
    """Previous location merged by rehearsal (weight update), if any."""
    retrieved: list[int] = field(default_factory=list)
    """Locations brought back from LTM this keyframe."""
    transferred: list[int] = field(default_factory=list)
    """Locations moved to LTM this keyframe."""
    elapsed_ms: float = 0.0
    """Processing time measured with the detector's clock."""


class GeometricVerifier:
    """PnP RANSAC between the query's keypoints and the candidate's 3D points matched through visual words."""

    def __init__(
        self,
        camera_matrix: ArrayLike,
        camera_to_base: ArrayLike | None = None,
        min_inliers: int = 20,
        reprojection_error: float = 2.0,
        iterations: int = 300,
        max_depth: float = 0.0,
    ) -> None:
        """``camera_to_base`` is ``T_base_camera`` (identity when poses are camera poses)."""
        self.camera_matrix = np.asarray(camera_matrix, dtype=np.float64).reshape(3, 3)
        self.base_camera = np.eye(4) if camera_to_base is None else np.asarray(camera_to_base, dtype=np.float64)
        self.min_inliers = min_inliers
        self.reprojection_error = reprojection_error
        self.iterations = iterations
        self.max_depth = max_depth

    @staticmethod
    def correspondences(query: Signature, candidate: Signature) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Indices (query, candidate) of keypoints sharing a word that occurs exactly once in each."""

        def unique_index(word_ids: NDArray[np.int64]) -> dict[int, int]:
            words, first, counts = np.unique(word_ids, return_index=True, return_counts=True)
            return {int(w): int(i) for w, i, c in zip(words, first, counts, strict=True) if c == 1 and w >= 0}

        q_index, c_index = unique_index(query.word_ids), unique_index(candidate.word_ids)
        common = sorted(q_index.keys() & c_index.keys())
        return (
            np.array([q_index[w] for w in common], dtype=np.intp),
            np.array([c_index[w] for w in common], dtype=np.intp),
        )

    def verify(self, query: Signature, candidate: Signature) -> VerificationResult:
        """Estimate ``T_candidate_query``; rejected below ``min_inliers``."""
        try:
            import cv2
        except ImportError as err:
            raise MissingExtraError("opencv-python-headless", "slam") from err
        q_idx, c_idx = self.correspondences(query, candidate)
        points = candidate.points3d[c_idx].astype(np.float64)
        valid = np.isfinite(points).all(axis=1) & (points[:, 2] > 0) if len(points) else np.zeros(0, bool)
        if self.max_depth > 0 and len(points):
            valid &= points[:, 2] <= self.max_depth
        points = points[valid]
        pixels = query.keypoints[q_idx][valid].astype(np.float64)
        n = len(points)
        if n < max(self.min_inliers, 4):
            return VerificationResult(None, 0, n, f"only {n} correspondences (< {self.min_inliers})")
        # OpenCV's RANSAC draws from the global RNG; a fixed seed keeps verification deterministic.
        cv2.setRNGSeed(0)
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            points,
            pixels,
            self.camera_matrix,
            None,
            iterationsCount=self.iterations,
            reprojectionError=self.reprojection_error,
            confidence=0.99,
            flags=cv2.SOLVEPNP_EPNP,
        )
        count = 0 if inliers is None else len(inliers)
        if not ok or count < self.min_inliers:
            return VerificationResult(None, count, n, f"{count} PnP inliers (< {self.min_inliers})")
        rotation, _ = cv2.Rodrigues(rvec)
        query_cam_from_candidate_cam = make_pose(rotation, tvec.ravel())
        candidate_cam_from_query_cam = invert(query_cam_from_candidate_cam)
        transform = self.base_camera @ candidate_cam_from_query_cam @ invert(self.base_camera)
        return VerificationResult(transform, count, n, "accepted")


class LoopClosureDetector:
    """RTAB-Map's per-keyframe loop: memory update, likelihood, Bayes filter, decision, verification, transfer."""

    def __init__(
        self,
        memory: Memory,
        bayes: BayesFilter,
        verifier: GeometricVerifier,
        loop_threshold: float = 0.11,
        loop_ratio: float = 0.0,
        tf_idf: bool = True,
        time_threshold_ms: float = 0.0,
        clock: Callable[[], float] = time.perf_counter,
        loop_information: ArrayLike | None = None,
    ) -> None:
        """``clock`` returns seconds; tests inject a fake clock to make the time budget deterministic."""
        self.memory = memory
        self.bayes = bayes
        self.verifier = verifier
        self.loop_threshold = loop_threshold
        self.loop_ratio = loop_ratio
        self.tf_idf = tf_idf
        self.time_threshold_ms = time_threshold_ms
        self.clock = clock
        self.loop_information = (
            DEFAULT_LOOP_INFORMATION.copy() if loop_information is None else np.asarray(loop_information, float)
        )
        self._last_value = 0.0
        self.last_posterior: dict[int, float] = {}
        """Posterior of the last keyframe (``VIRTUAL_PLACE`` = -1 included)."""
        self.last_likelihood: dict[int, float] = {}
        """Normalised likelihood of the last keyframe."""

    def process(
        self,
        stamp: float,
        pose: ArrayLike,
        keypoints: ArrayLike,
        points3d: ArrayLike,
        descriptors: NDArray[np.generic],
        *,
        odometry_transform: ArrayLike | None = None,
        odometry_information: ArrayLike | None = None,
        rgb_compressed: bytes | None = None,
        depth_compressed: bytes | None = None,
    ) -> LoopHypothesis:
        """Add one keyframe and decide whether it closes a loop (see the module docstring)."""
        start = self.clock()
        added = self.memory.add(
            stamp,
            pose,
            keypoints,
            points3d,
            descriptors,
            odometry_transform=odometry_transform,
            odometry_information=odometry_information,
            rgb_compressed=rgb_compressed,
            depth_compressed=depth_compressed,
        )
        query = added.signature
        match_id: int | None = None
        value = 0.0
        transform = None
        inliers = 0
        reason = "working memory is empty"
        retrieved: list[int] = []
        protected: set[int] = set()
        if self.memory.wm:
            raw = self.memory.likelihood(query, self.tf_idf)
            self.last_likelihood = adjust_likelihood(raw)
            self.last_posterior = self.bayes.compute_posterior(self.last_likelihood, self.memory.neighbors)
            locations = {i: p for i, p in self.last_posterior.items() if i != VIRTUAL_PLACE}
            match_id = max(locations, key=lambda i: (locations[i], -i))
            value = 1.0 - self.last_posterior[VIRTUAL_PLACE]
            retrieved = self.memory.retrieve(self.memory.retrieval_candidates(match_id))
            protected = {match_id, *retrieved}
            if value < self.loop_threshold:
                reason = f"hypothesis {value:.3f} below threshold {self.loop_threshold}"
            elif self.loop_ratio > 0 and value < self.loop_ratio * self._last_value:
                reason = f"hypothesis {value:.3f} below {self.loop_ratio} x previous {self._last_value:.3f}"
            else:
                verification = self.verifier.verify(query, self.memory.signatures[match_id])
                inliers = verification.inliers
                reason = verification.reason
                transform = verification.transform
            self._last_value = value
        accepted = transform is not None
        if accepted and match_id is not None and transform is not None:
            kind = LinkType.LOOP if self.memory.signatures[match_id].map_id == query.map_id else LinkType.INTER_SESSION
            link = Link(match_id, query.id, kind, transform, self.loop_information.copy())
            self.memory.add_link(link, update_weights=True)
            logger.info("loop closure %d -> %d (p=%.3f, %d inliers)", query.id, match_id, value, inliers)
        elapsed_ms = (self.clock() - start) * 1000.0
        over_budget = self.time_threshold_ms > 0 and elapsed_ms > self.time_threshold_ms
        transferred = self.memory.enforce_limits(over_budget, protected, retrieved=len(retrieved))
        return LoopHypothesis(
            query_id=query.id,
            match_id=match_id,
            probability=value,
            accepted=accepted,
            transform=transform,
            inliers=inliers,
            reason=reason,
            rehearsed_with=added.rehearsed_with,
            retrieved=retrieved,
            transferred=transferred,
            elapsed_ms=elapsed_ms,
        )


def load_memory(
    database: MapDatabase, loop: LoopClosureConfig, memory: MemoryConfig, new_session: bool = True
) -> Memory:
    """The memory stored in ``database`` configured like a new one (pass it to ``existing_memory``)."""
    return Memory.load(
        database,
        nndr_ratio=loop.nndr_ratio,
        max_distance=loop.max_word_distance,
        new_session=new_session,
        stm_size=memory.stm_size,
        rehearsal_similarity=memory.rehearsal_similarity,
        max_wm_size=memory.max_wm_size,
        max_retrieved=memory.max_retrieved,
        keep_images=memory.keep_images,
    )


def make_loop_closure_detector(
    loop: LoopClosureConfig,
    memory: MemoryConfig,
    camera_matrix: ArrayLike,
    camera_to_base: ArrayLike | None = None,
    clock: Callable[[], float] | None = None,
    existing_memory: Memory | None = None,
) -> LoopClosureDetector:
    """Build the detector from configuration (``existing_memory``: continue a map loaded from map.db)."""
    if existing_memory is not None:
        if existing_memory.vocabulary.kind != loop.descriptor_kind:
            raise SlamError(
                f"loop_closure.descriptor_kind = {loop.descriptor_kind!r} but the loaded map uses "
                f"{existing_memory.vocabulary.kind!r} descriptors"
            )
        mem = existing_memory
    else:
        vocabulary = VisualVocabulary(loop.descriptor_kind, loop.nndr_ratio, loop.max_word_distance)
        mem = Memory(
            vocabulary,
            stm_size=memory.stm_size,
            rehearsal_similarity=memory.rehearsal_similarity,
            max_wm_size=memory.max_wm_size,
            max_retrieved=memory.max_retrieved,
            keep_images=memory.keep_images,
        )
    verifier = GeometricVerifier(
        camera_matrix,
        camera_to_base,
        min_inliers=loop.min_inliers,
        reprojection_error=loop.pnp_reprojection_error,
        iterations=loop.pnp_iterations,
        max_depth=loop.pnp_max_depth,
    )
    return LoopClosureDetector(
        mem,
        BayesFilter(loop.prediction_lc, loop.virtual_place_prior),
        verifier,
        loop_threshold=loop.loop_threshold,
        loop_ratio=loop.loop_ratio,
        tf_idf=loop.tf_idf_likelihood,
        time_threshold_ms=memory.time_threshold_ms,
        clock=clock if clock is not None else time.perf_counter,
    )
