"""Configuration of the loop-closure side of the SLAM: detector (vocabulary, Bayes filter, verification) and
memory management (STM/WM/LTM). Defaults are RTAB-Map's; the RTAB-Map parameter name is given per field.

``fleetslam.slam.config.SlamConfig`` composes these two sections (``loop_closure`` and ``memory``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from fleetslam.config import ConfigModel

DEFAULT_PREDICTION_LC: tuple[float, ...] = (
    0.1,
    0.36,
    0.30,
    0.16,
    0.062,
    0.0151,
    0.00255,
    0.000324,
    2.5e-05,
    1.3e-06,
    4.8e-08,
    1.5e-09,
    3.1e-11,
)


class LoopClosureConfig(ConfigModel):
    """Appearance-based loop-closure detection: vocabulary, Bayes filter, hypothesis selection, verification."""

    descriptor_kind: Literal["binary", "float"] = "binary"
    """Descriptor family: 'binary' (ORB/BRIEF, Hamming distance) or 'float' (SIFT/SURF, L2 distance)."""

    nndr_ratio: float = Field(0.8, gt=0.0, le=1.0)
    """Nearest-neighbour distance ratio (RTAB-Map Kp/NndrRatio): a descriptor joins its nearest word only if
    d1 < ratio * d2, otherwise it becomes a new word."""

    max_word_distance: float = Field(0.0, ge=0.0)
    """Absolute bound on the distance to the nearest word for a match (0 = no bound, NNDR only). Hamming bits
    for binary descriptors, L2 units for float ones."""

    max_words: int = Field(400, ge=0)
    """Keypoints of a keyframe that become visual words, the strongest first (0 = all; RTAB-Map Kp/MaxFeatures,
    500). Every keyframe searches all words in RAM and adds those it does not match: at 1000 features a keyframe
    brought ~600 new words and the search took 340 ms at 100 locations, growing with the working memory. The
    verification still matches every keypoint."""

    tf_idf_likelihood: bool = True
    """Score locations with TF-IDF over the inverted index (RTAB-Map Kp/TfIdfLikelihoodUsed); if false, with the
    ratio of common words (RTAB-Map's Signature::compareTo)."""

    loop_threshold: float = Field(0.11, ge=0.0, le=1.0)
    """Loop-closure threshold H on the hypothesis probability (RTAB-Map Rtabmap/LoopThr)."""

    loop_ratio: float = Field(0.0, ge=0.0, le=1.0)
    """Hypothesis ratio test: reject when the hypothesis value is below this ratio times the previous one
    (RTAB-Map Rtabmap/LoopRatio; 0 disables)."""

    prediction_lc: tuple[float, ...] = DEFAULT_PREDICTION_LC
    """Transition model (RTAB-Map Bayes/PredictionLC): [location -> virtual place, location -> itself,
    neighbours at graph depth 1, 2, ...]."""

    virtual_place_prior: float = Field(0.9, ge=0.0, le=1.0)
    """Probability that a 'new place' stays a new place (RTAB-Map Bayes/VirtualPlacePriorThr)."""

    min_inliers: int = Field(12, ge=4)
    """Minimum PnP RANSAC inliers to accept a loop closure or a relocalisation (RTAB-Map Vis/MinInliers, whose
    default is 20). 12, with ``memory.stm_size=30``: at 320×240 a revisit from another heading (the hand-held figure
    eight at 30 Hz coming back to its start) shares only 7–19 correspondences with depth, so 20 accepted 2 loops
    there (4.60 cm ATE, the odometry's drift) and 12 accepts 14 (2.35 cm); the 12 procedural hand-held 320×240 cells
    of the benchmark matrix: 11 within 3 cm instead of 10, mean 2.33 → 2.06 cm, worst 4.60 → 3.04 cm. Alone, 12 also
    admitted loops to keyframes just out of the short-term memory, up to 2.8° off the truth (see ``stm_size``).
    The count does not tell an alias from a true loop (a rack 4 m further on passes with 42 inliers and both PnP
    directions within 1 cm): the pose graph's consistency check (``backend.optimize_max_error``) rejects those."""

    pnp_reprojection_error: float = Field(2.0, gt=0.0)
    """PnP RANSAC inlier threshold in pixels (RTAB-Map Vis/PnPReprojError)."""

    pnp_iterations: int = Field(300, ge=10)
    """PnP RANSAC iterations (RTAB-Map Vis/Iterations)."""

    pnp_max_depth: float = Field(0.0, ge=0.0)
    """Ignore candidate 3D points farther than this (metres, 0 = no limit; RTAB-Map Vis/MaxDepth)."""

    verification_correspondences: Literal["descriptors", "words"] = "descriptors"
    """How verification pairs keypoints: 'descriptors' re-matches the two locations' descriptors (mutual
    nearest neighbours + ratio test, as RTAB-Map's registration does); 'words' pairs keypoints whose visual
    word occurs once in each (cheaper; an incremental vocabulary often splits one landmark into several words)."""

    max_direction_disagreement: float = Field(0.05, ge=0.0)
    """Also solve PnP the other way (query points in the candidate image) and reject when the two estimates
    differ by more than this many metres (0 = skip the check): repeated patterns fool one direction."""

    max_direction_disagreement_deg: float = Field(2.0, gt=0.0)
    """Rotation tolerance between the two PnP directions (degrees)."""

    peer_min_inliers: int = Field(20, ge=4)
    """Minimum PnP RANSAC inliers to accept a place recognised in another agent's map (collaborative SLAM; the
    depth refinement then keeps ``ClosureQuality.min_kept_fraction`` of this). Kept at RTAB-Map's 20 when
    ``min_inliers`` went to 12: a wrong closure between two agents' maps misplaces a whole map in the fleet's, and
    12 was measured only on single-agent loops (where the pose graph's consistency check rejects the aliases)."""


class MemoryConfig(ConfigModel):
    """Memory management: short-term memory, working memory, long-term memory (RTAB-Map Mem/* parameters)."""

    stm_size: int = Field(30, ge=1)
    """Number of most recent locations kept in the short-term memory, never loop candidates (Mem/STMSize, whose
    default is 10 at RTAB-Map's 1 Hz detection rate: 10 s of motion). Keyframes here come every 1–3 frames, so 10
    is well under a second at 30 Hz; loops to keyframes 10–13 back (0.2–0.7 m away) were off the truth by up to
    7.6 cm and 2.8° with ``loop_closure.min_inliers=12`` — worse than the odometry over that span (under 1.5 cm) —
    and 30 keeps them out: the worst loop the pose graph kept on the 12 procedural hand-held 320×240 cells went
    from 7.6 cm / 2.8° to 6.5 cm / 1.7° (with 20 inliers and 10: 8.2 cm / 1.7°)."""

    rehearsal_similarity: float = Field(0.6, ge=0.0, le=1.0)
    """Similarity of word sets above which a new location is merged with the previous one (weight update,
    Mem/RehearsalSimilarity)."""

    max_wm_size: int = Field(300, ge=0)
    """Maximum number of locations in the working memory before transfers to LTM (0 = unlimited;
    RTAB-Map Rtabmap/MemoryThr). Bounds the cost of every keyframe's word search and loop hypothesis (they grow
    with the working memory; unbounded, a robot that patrols for minutes slows down until it drops most frames):
    300 keyframes are a couple of minutes of driving, more than a lap of the demo's routes."""

    time_threshold_ms: float = Field(0.0, ge=0.0)
    """Processing-time budget per keyframe in milliseconds; above it, locations are transferred from WM to LTM
    (0 = no budget; RTAB-Map Rtabmap/TimeThr)."""

    max_retrieved: int = Field(2, ge=0)
    """Maximum number of locations retrieved from LTM around the highest hypothesis per keyframe
    (RTAB-Map Rtabmap/MaxRetrieved)."""

    keep_images: bool = True
    """Keep the compressed RGB/depth images given with a location (stored in map.db; Mem/ImageKept)."""
