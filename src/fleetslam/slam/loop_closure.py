"""Appearance-based loop-closure detection with geometric verification (RTAB-Map ``Rtabmap::process``).

The pipeline calls :meth:`LoopClosureDetector.process` once per keyframe::

    detector = make_loop_closure_detector(cfg.loop_closure, cfg.memory, camera_matrix, T_base_camera)
    hyp = detector.process(KeyframeObservation(stamp, T_world_base,
                                               KeyframeFeatures(keypoints_uv, points_cam, descriptors),
                                               odometry_transform=T_prev_new, odometry_information=info6x6,
                                               rgb_compressed=jpeg_bytes, depth_compressed=png_bytes))
    # hyp.query_id is the new location's id (the pose-graph node id); the odometry link
    # previous -> new is already in detector.memory. If hyp.accepted: add the factor
    # between hyp.match_id and hyp.query_id with hyp.transform (T_match_query) and
    # detector.memory.signatures[hyp.match_id].links[hyp.query_id].information.
    # At the end of the run:  with MapDatabase(out / "map.db") as db: detector.save(db)
    # Next session:           with MapDatabase(path) as db: mem = Memory.load(db, new_session=True, ...)
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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.errors import MissingExtraError, SlamError
from fleetslam.geometry import invert, make_pose, planar_camera_pose, rotation_angle
from fleetslam.slam.bayes_filter import VIRTUAL_PLACE, BayesFilter, adjust_likelihood
from fleetslam.slam.frontend import KeyframeObservation
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.matching import match_mutual
from fleetslam.slam.memory import Memory
from fleetslam.slam.pose_refinement import planar_basis, refine_pose
from fleetslam.slam.signature import Link, LinkType, Signature
from fleetslam.slam.vocabulary import VisualVocabulary

if TYPE_CHECKING:
    from fleetslam.slam.database import MapDatabase

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
    off_plane: int = 0
    """Forward PnP inliers off the plane that holds most of them (0 when rejected before they are counted)."""
    matches: tuple[NDArray[np.intp], NDArray[np.intp]] | None = None
    """(query, candidate) keypoint indices of the forward PnP inliers of an accepted transform (for a refinement)."""

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
    """PnP RANSAC between the query's keypoints and the candidate's 3D points (RTAB-Map's RegistrationVis).

    Correspondences come from descriptor matching (``"descriptors"``, default: mutual nearest neighbours with
    the ratio test, as RTAB-Map re-matches features for registration) or from shared visual words that occur
    once in each location (``"words"``, cheaper, but a growing vocabulary splits one landmark into several
    words). The pose is refined by Levenberg–Marquardt on the inliers. With ``max_disagreement`` set, PnP is
    also solved the other way (the query's 3D points in the candidate's image) and the two estimates must
    agree: a repeated pattern (shelves, tiles) can give a consistent but wrong solution one way, rarely the
    same one both ways.
    """

    def __init__(
        self,
        camera_matrix: ArrayLike,
        camera_to_base: ArrayLike | None = None,
        min_inliers: int = 20,
        reprojection_error: float = 2.0,
        iterations: int = 300,
        max_depth: float = 0.0,
        correspondences: str = "descriptors",
        nndr_ratio: float = 0.8,
        max_disagreement: tuple[float, float] | None = (0.05, np.radians(2.0)),
        min_off_plane: int = 0,
        plane_tolerance: float = 0.05,
    ) -> None:
        """``camera_to_base`` is ``T_base_camera`` (identity when poses are camera poses);
        ``max_disagreement`` is (metres, radians) between the two PnP directions, None to skip that check;
        ``min_off_plane``: inliers that must lie farther than ``plane_tolerance`` (m) from the plane holding most of
        them (0: no such check). A plane with a periodic texture (floor tiles) admits PnP solutions shifted by the
        period, in both directions alike; points off that plane pin the shift."""
        if correspondences not in ("descriptors", "words"):
            raise SlamError(
                f"loop verification: correspondences must be 'descriptors' or 'words', got {correspondences!r}"
            )
        self.camera_matrix = np.asarray(camera_matrix, dtype=np.float64).reshape(3, 3)
        self.base_camera = np.eye(4) if camera_to_base is None else np.asarray(camera_to_base, dtype=np.float64)
        self.min_inliers = min_inliers
        self.reprojection_error = reprojection_error
        self.iterations = iterations
        self.max_depth = max_depth
        self.mode = correspondences
        self.nndr_ratio = nndr_ratio
        self.max_disagreement = max_disagreement
        self.min_off_plane = min_off_plane
        self.plane_tolerance = plane_tolerance
        self.planar_mounting: NDArray[np.float64] | None = None
        """T_base_camera of a ground robot: transforms are then solved for x, y and yaw of the base only."""

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

    def _valid_points(self, points: NDArray[np.floating]) -> NDArray[np.bool_]:
        valid = np.isfinite(points).all(axis=1) & (points[:, 2] > 0) if len(points) else np.zeros(0, bool)
        if self.max_depth > 0 and len(points):
            valid &= points[:, 2] <= self.max_depth
        return valid

    def _pnp(
        self, points: NDArray[np.float64], pixels: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.bool_]]:
        """``T_camera_points`` (the points' frame seen from the camera of ``pixels``) and the inlier mask."""
        import cv2

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
        if not ok or inliers is None or len(inliers) < 4:
            mask = np.zeros(len(points), bool)
            if inliers is not None:
                mask[inliers.reshape(-1)] = True
            return None, mask
        index = inliers.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(points[index], pixels[index], self.camera_matrix, None, rvec, tvec)
        rotation, _ = cv2.Rodrigues(rvec)
        pose = make_pose(rotation, tvec.ravel())
        if self.planar_mounting is not None:
            # A ground robot's two views differ by x, y and yaw of its base: solve for those three only.
            inlier_mask = self._inliers(pose, points, pixels)
            start = invert(planar_camera_pose(invert(pose), self.planar_mounting))
            pose = refine_pose(
                start, points[inlier_mask], pixels[inlier_mask], self.camera_matrix,
                huber_px=self.reprojection_error, basis=planar_basis(self.planar_mounting),
            )  # fmt: skip
        # Inliers again under the refined pose: the count that is compared with min_inliers.
        return pose, self._inliers(pose, points, pixels)

    def _inliers(
        self, pose: NDArray[np.float64], points: NDArray[np.float64], pixels: NDArray[np.float64]
    ) -> NDArray[np.bool_]:
        camera = points @ pose[:3, :3].T + pose[:3, 3]
        in_front = camera[:, 2] > 1e-6
        uv = camera[:, :2] / np.where(in_front, camera[:, 2], 1.0)[:, None]
        uv = uv * np.diag(self.camera_matrix)[:2] + self.camera_matrix[:2, 2]
        error = np.linalg.norm(uv - pixels, axis=1)
        return np.asarray(in_front & (error <= self.reprojection_error))

    def verify(self, query: Signature, candidate: Signature) -> VerificationResult:
        """Estimate ``T_candidate_query``; rejected below ``min_inliers`` or when the two directions disagree."""
        try:
            import cv2  # noqa: F401
        except ImportError as err:
            raise MissingExtraError("opencv-python-headless", "slam") from err
        if self.mode == "words":
            q_idx, c_idx = self.correspondences(query, candidate)
        else:
            q_idx, c_idx = match_mutual(query.descriptors, candidate.descriptors, self.nndr_ratio)
        candidate_points = candidate.points3d[c_idx].astype(np.float64)
        valid = self._valid_points(candidate_points)
        n = int(valid.sum())
        if n < max(self.min_inliers, 4):
            return VerificationResult(None, 0, n, f"only {n} correspondences (< {self.min_inliers})")
        pixels = query.keypoints[q_idx][valid].astype(np.float64)
        T_query_candidate, forward_inliers = self._pnp(candidate_points[valid], pixels)
        count = int(forward_inliers.sum())
        if T_query_candidate is None or count < self.min_inliers:
            return VerificationResult(None, count, n, f"{count} PnP inliers (< {self.min_inliers})")
        candidate_from_query = invert(T_query_candidate)
        if self.max_disagreement is not None:
            query_points = query.points3d[q_idx].astype(np.float64)
            back = self._valid_points(query_points)
            reverse, reverse_count = (None, 0)
            if back.sum() >= max(self.min_inliers, 4):
                reverse, reverse_inliers = self._pnp(
                    query_points[back], candidate.keypoints[c_idx][back].astype(np.float64)
                )
                reverse_count = int(reverse_inliers.sum())
            if reverse is None or reverse_count < self.min_inliers:
                return VerificationResult(
                    None, count, n, f"reverse PnP: {reverse_count} inliers (< {self.min_inliers})"
                )
            difference = invert(reverse) @ candidate_from_query
            metres, radians = float(np.linalg.norm(difference[:3, 3])), rotation_angle(difference)
            if metres > self.max_disagreement[0] or radians > self.max_disagreement[1]:
                return VerificationResult(
                    None, count, n, f"the two PnP directions disagree by {metres:.3f} m, {np.degrees(radians):.2f} deg"
                )
        off_plane = off_plane_count(candidate_points[valid][forward_inliers], self.plane_tolerance)
        if off_plane < self.min_off_plane:
            return VerificationResult(
                None, count, n, f"{off_plane} inliers off their dominant plane (< {self.min_off_plane})", off_plane
            )
        transform = self.base_camera @ candidate_from_query @ invert(self.base_camera)
        matches = (q_idx[valid][forward_inliers], c_idx[valid][forward_inliers])
        return VerificationResult(transform, count, n, "accepted", off_plane, matches)


def off_plane_count(points: NDArray[np.float64], tolerance: float, *, trials: int = 200) -> int:
    """How many of ``points`` lie farther than ``tolerance`` from the plane that holds the most of them (RANSAC over
    triples, seeded: deterministic); 0 for fewer than four (they always lie on one plane)."""
    n = len(points)
    if n < 4:
        return 0
    rng = np.random.default_rng(0)
    triples = rng.integers(0, n, size=(trials, 3))
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    good = lengths > 1e-9
    if not good.any():
        return 0  # all on one line (or one point): no more than a plane
    normals = normals[good] / lengths[good, None]
    offsets = np.einsum("kj,kj->k", normals, a[good])
    on_plane = np.abs(points @ normals.T - offsets) <= tolerance
    return int(n - on_plane.sum(axis=0).max())


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

    def process(self, observation: KeyframeObservation) -> LoopHypothesis:
        """Add one keyframe and decide whether it closes a loop (see the module docstring); the features'
        ``responses`` choose which keypoints become words when the memory limits them.

        Raises:
            SlamError: the observation has no features.
        """
        start = self.clock()
        added = self.memory.add(observation)
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

    # -- what the pipeline asks of the loop-closure side besides process() ----------------------------------------
    def set_planar_mounting(self, base_camera: NDArray[np.float64] | None) -> None:
        """A ground robot's camera mounting (T_base_camera): verification then solves for the base's x, y and yaw
        only; None: full 6-DoF transforms."""
        self.verifier.planar_mounting = base_camera

    def locations(self) -> list[int]:
        """Ids of every location in memory (STM, WM and LTM), newest first."""
        return sorted(self.memory.signatures, reverse=True)

    def relocalize(
        self, observation: KeyframeObservation, candidates: Iterable[int]
    ) -> tuple[int, VerificationResult] | None:
        """The first of the ``candidates`` (location ids) that the observation passes geometric verification
        against, with the result (``transform`` is T_location_query); None when none does or it has no features."""
        features = observation.features
        if features is None:
            return None
        query = Signature(
            id=-1,
            stamp=observation.stamp,
            pose=observation.pose,
            keypoints=np.asarray(features.keypoints, np.float32),
            points3d=np.asarray(features.points3d, np.float32),
            descriptors=np.asarray(features.descriptors),
        )
        for location in candidates:
            verification = self.verifier.verify(query, self.memory.signatures[location])
            if verification.transform is not None:
                return location, verification
        return None

    def memory_sizes(self) -> dict[str, int]:
        """Locations in the short-term, working and long-term memory (``stm``, ``wm``, ``ltm``)."""
        return {"stm": len(self.memory.stm), "wm": len(self.memory.wm), "ltm": len(self.memory.ltm)}

    def bag_of_words(self, location_id: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Word ids and TF-IDF weights of a location (see :meth:`Memory.bag_of_words`)."""
        return self.memory.bag_of_words(location_id)

    def save(self, database: MapDatabase) -> None:
        """Write the whole memory (locations, links, vocabulary) to ``database``; :meth:`Memory.load` reads it."""
        self.memory.save(database)


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
            max_words=loop.max_words,
        )
    verifier = GeometricVerifier(
        camera_matrix,
        camera_to_base,
        min_inliers=loop.min_inliers,
        reprojection_error=loop.pnp_reprojection_error,
        iterations=loop.pnp_iterations,
        max_depth=loop.pnp_max_depth,
        correspondences=loop.verification_correspondences,
        nndr_ratio=loop.nndr_ratio,
        max_disagreement=(
            (loop.max_direction_disagreement, np.radians(loop.max_direction_disagreement_deg))
            if loop.max_direction_disagreement > 0
            else None
        ),
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
