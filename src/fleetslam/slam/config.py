"""Configuration of the RGB-D graph SLAM: features, odometry, back-end, and the loop-closure side's sections.

Defaults follow RTAB-Map where a parameter has an equivalent (named per field).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from fleetslam.config import ConfigModel
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig


class FeatureConfig(ConfigModel):
    """Keypoint detection and description."""

    kind: Literal["orb", "sift", "akaze"] = "orb"
    """Detector/descriptor: 'orb' (binary, fast, default), 'sift' (float), 'akaze' (binary)."""

    max_features: int = Field(default=1000, ge=10)
    """Keypoints kept per image (RTAB-Map Vis/MaxFeatures)."""

    grid_rows: int = Field(default=4, ge=1)
    """Rows of the bucketing grid: the best keypoints are kept per cell for even image coverage."""

    grid_cols: int = Field(default=4, ge=1)
    """Columns of the bucketing grid."""

    orb_fast_threshold: int = Field(default=8, ge=1)
    """FAST threshold of the ORB detector (lower finds more corners on weak texture)."""

    orb_levels: int = Field(default=4, ge=1)
    """ORB pyramid levels (fewer is faster; frame-to-frame motion is small)."""

    orb_patch_size: int = Field(default=31, ge=15)
    """ORB's descriptor patch (pixels) on a 640-pixel-wide image; scaled down with smaller images, so that it
    covers the same part of the scene and features come as close to the border."""

    subpixel_window: int = Field(default=0, ge=0)
    """Sub-pixel keypoint positions (ORB): each kept keypoint moves to the corner that the image gradients in a
    window around it define (:class:`~fleetslam.slam.features.SubpixelRefiner`); this is the window's half-size
    in pixels on a 640-pixel-wide image (scaled with the image like ``orb_patch_size``, and by the pixel size of
    the keypoint's pyramid level); a keypoint that would leave its window, or whose window holds an edge or a flat
    patch rather than a corner, stays where ORB found it. 0: keypoints stay on their level's pixel grid.
    Descriptors are computed where ORB found the keypoints either way. Measured with 10 (benchmarks/slam_matrix.py,
    26 November 2026, ATE cm at 5/10/15/30 Hz, defaults → 10): procedural hall, hand-held, 320×240, loop_revisit
    1.44/1.44/2.33/1.52 → 1.84/1.71/1.57/1.70, survey 2.74/3.52/4.72/2.88 → 2.57/2.34/4.74/2.79, figure eight
    1.95/1.97/2.15/4.92 → 1.74/1.99/1.87/2.60 (11 of 12 cells within 3 cm instead of 9); ground, 320×240, all within
    2 cm (0.56–1.58, 10 of 12 better); but the photographic hall (never used for tuning), hand-held, 320×240:
    loop_revisit 1.61/1.49/1.47/1.50 → 1.25/1.34/1.06/0.84, survey 2.32/1.64/1.74/1.63 → 3.17/2.56/1.52/1.84,
    figure eight 0.98/1.24/0.89/1.25 → 1.02/0.95/0.83/4.01 (two cells over 3 cm); 640×480 survey at 5 Hz,
    hand-held, 1.33 → 1.47 cm and tracking 11.5–12.1 → 15.5 ms per frame; the photographic hall at 640×480,
    hand-held, 5 Hz: loop_revisit 0.26 → 1.78 cm, survey 0.32 → 1.54 cm, tracking over 20 ms per frame. Hence not
    the default."""


class OdometryConfig(ConfigModel):
    """The odometry front-end; the other fields configure the ``visual`` one, frame-to-local-map visual odometry
    (RTAB-Map Odom/Strategy=0, F2M)."""

    kind: str = "visual"
    """Front-end, by its name in the registry (:data:`fleetslam.slam.frontend.FRONT_ENDS`; ``visual`` is the only
    built-in one). A front-end without features runs with loop closure and relocalisation off."""

    min_inliers: int = Field(default=15, ge=4)
    """Below this many PnP inliers tracking is lost (RTAB-Map Vis/MinInliers)."""

    match_ratio: float = Field(default=0.8, gt=0.0, le=1.0)
    """Nearest-neighbour distance ratio when matching frame descriptors to the local map. Measured with 0.95 and
    ``window_fixed_keyframes=6`` (benchmarks/slam_matrix.py), procedural hall, 320×240: hand-held survey
    3.48/3.17/7.42/4.50 → 3.33/2.33/2.78/2.94 cm at 5/10/15/30 Hz, figure eight 3.20/2.13/2.99/5.50 →
    2.18/2.96/1.89/1.69 cm (its odometry alone 7.5/9.6/6.6/6.5 → 3.9/3.1/3.2/2.8 cm), loop_revisit
    2.75/1.84/4.54/2.44 → 1.65/1.67/1.85/1.35 cm (11 of the 12 cells within 3 cm instead of 5); 640×480 survey,
    5/10 Hz, hand-held 2.21/2.92 → 1.63/1.34 cm, ground at 5 Hz 1.39 → 1.13 cm, tracking 14-16 ms per frame
    instead of 16-17 (fewer keyframes); but the ground robot's cells, all within 2 cm either way, moved by -0.53
    to +0.49 cm
    (loop_revisit 1.27/1.08/1.08/0.92 → 1.22/1.35/1.01/1.35, survey 1.09/0.99/1.16/1.76 → 1.58/1.17/1.41/1.46,
    figure eight 1.01/1.03/1.43/1.65 → 0.92/0.99/1.23/1.12 cm), and on the photographic hall (320×240, 5/15 Hz)
    the hand-held survey went 3.14/2.41 → 1.91/3.51 cm, the ground survey 2.30/1.56 → 1.26/1.58 cm, the figure
    eight 1.18/0.90 → 1.27/1.12 cm (hand-held) and 1.26/0.87 → 0.92/1.17 cm (ground). Hence not the default."""

    pnp_reprojection_error: float = Field(default=2.0, gt=0.0)
    """RANSAC inlier threshold in pixels (RTAB-Map Vis/PnPReprojError)."""

    pnp_iterations: int = Field(default=100, ge=10)
    """RANSAC iterations (RTAB-Map Vis/Iterations)."""

    min_depth: float = Field(default=0.1, ge=0.0)
    """Closer depth readings are ignored (metres)."""

    max_depth: float = Field(default=6.0, gt=0.0)
    """Farther depth readings are ignored (metres; Kinect noise grows with z²)."""
    depth_as_mask: bool = False
    """Detect features only where the depth is valid (RTAB-Map Vis/DepthAsMask, on there by default): features
    without depth give no 3D point. Off by default here: on the simulated plant it gave more, but mostly
    floor-tile, features and a larger drift (ATE 5.3 vs 4.2 cm on the 600-frame loop)."""

    keyframe_inlier_ratio: float = Field(default=0.4, ge=0.0, le=1.0)
    """New keyframe when inliers fall below this ratio of the features of the last keyframe
    (RTAB-Map Odom/KeyFrameThr)."""

    keyframe_translation: float = Field(default=0.25, gt=0.0)
    """New keyframe after this much translation from the last one (metres)."""

    keyframe_rotation_deg: float = Field(default=15.0, gt=0.0)
    """New keyframe after this much rotation from the last one (degrees)."""

    local_map_size: int = Field(default=3000, ge=100)
    """Maximum 3D points in the local map; the oldest leave first (RTAB-Map OdomF2M/MaxSize)."""

    max_descriptor_distance: float = Field(default=0.0, ge=0.0)
    """Guided matches of binary descriptors (ORB/AKAZE) must lie within this many Hamming bits (0 = no bound;
    float descriptors use the ratio test only). ORB-SLAM uses 100; on the simulated plant that bound gave
    more drift (ATE 10.6 vs 6.2 cm before loop closure), PnP RANSAC already removing the stray matches."""
    search_radius: float = Field(default=15.0, gt=0.0)
    """Landmarks are matched within this many pixels of where the motion prediction projects them (pixels of a
    640-pixel-wide image, scaled with the width); a frame that tracks poorly is searched again at 4× the radius,
    then across the whole image."""

    same_point_radius: float = Field(default=0.0, ge=0.0)
    """Landmarks the prediction projects within this many pixels (of a 640-pixel-wide image, scaled with the
    width) of a keypoint's nearest landmark are not its rival in the ratio test: they are the same point made
    twice. 0 = every candidate competes (the default). Each keyframe makes landmarks of the keypoints it did not
    track, and where the ratio test had rejected one, its landmark is made again beside the old one: from then on
    the two reject each other. On the procedural hall's hand-held survey at 320×240 and 5 Hz, 6 finds 40 % more
    guided matches (median 84 → 118 per frame). Measured with 6 (benchmarks/slam_matrix.py), procedural hall,
    320×240, hand-held, survey 3.48/3.17/7.42/4.50 cm at 5/10/15/30 Hz and figure eight 3.20/2.13/2.99/5.50 cm
    by default: alone 7.68/4.59/2.76/4.11 and 3.32/2.64/2.74/2.55 cm; with ``window_fixed_keyframes=6``
    5.34/5.27/2.99/4.13 and 2.96/2.35/2.13/1.82 cm; with ``triangulation_keyframes=6`` 2.23/2.92/2.33/4.04 and
    2.70/3.17/3.33/2.26 cm. Alone, the figure eight's odometry drifts less (7.5/9.6/6.6/6.5 → 4.6/3.1/3.4/3.2 cm)
    but the survey's 5 and 10 Hz cells got worse; hence not the default."""
    fuse_landmarks: bool = True
    """After each keyframe, before the window's adjustment, landmarks made twice are merged (ORB-SLAM's local
    mapping, ``SearchInNeighbors``; :mod:`~fleetslam.slam.landmark_fusion`): the local map's landmarks are projected
    into the new keyframe, and where one falls on a keypoint that observes another landmark, within the χ² gate of
    reprojection and depth and ``fuse_descriptor_distance`` of its descriptor, the two become the one with more
    observations, everywhere they are referenced (the local map, the window and its fixed keyframes); one that falls
    on a keypoint without a landmark gains that observation. Binary descriptors only. Used only where no wheel prior
    ties the window (as ``window_fixed_keyframes``), so a ground robot's results do not change, to the bit: with the
    wheels it moved 9 of the procedural hall's 12 ground cells at 320×240 by +0.02 to +0.79 cm (all within 2 cm).
    Measured (benchmarks/slam_matrix.py), hand-held, procedural hall, 320×240, ATE at 5/10/15/30 Hz: survey
    3.48/3.17/7.42/4.50 → 2.74/3.52/4.72/2.88 cm, figure eight 3.20/2.13/2.99/5.50 → 1.95/1.97/2.15/4.92 cm,
    loop_revisit 2.75/1.84/4.54/2.44 → 1.44/1.44/2.33/1.52 cm (9 of 12 cells within 3 cm instead of 5); more in
    docs/slam.md ("Tried on those cells"). Projecting the new keyframe's landmarks into the window's other keyframes
    as well (ORB-SLAM fuses both ways) made those cells worse (up to 10.5 cm)."""
    fuse_descriptor_distance: float = Field(default=50.0, gt=0.0)
    """Largest Hamming distance (bits) between a landmark's descriptor and the keypoint it is fused with (ORB-SLAM's
    ``TH_LOW``)."""
    max_prediction_error: float = Field(default=0.1, gt=0.0)
    """A pose farther than this from the motion prediction (metres per 1/30 s of frame interval) is a failure,
    not motion: a ground robot cannot jump that far between frames."""

    max_prediction_error_deg: float = Field(default=5.0, gt=0.0)
    """A pose rotated more than this from the prediction (degrees per 1/30 s of frame interval) is a failure."""

    motion_prior_acceleration: float = Field(default=3.0, ge=0.0)
    """Standard deviation of the linear acceleration (m/s², per axis) that the pose refinement allows away from a
    constant-velocity prediction: with Δt between frames the prediction is a prior of σ = ½·a·Δt² beside the
    reprojection errors, which keeps frames with few or far points (PnP ill-conditioned) where the motion says
    they are, at any camera rate. With wheel odometry the prediction is the wheels' motion instead, off by
    ``wheel_drift``. 0 = no prior (reprojection and depth errors only). A prediction the matches clearly
    contradict (``motion_prior_gate``) is dropped, so a hand-held jerk is not smoothed away."""
    motion_prior_angular_acceleration: float = Field(default=5.0, gt=0.0)
    """Standard deviation of the angular acceleration (rad/s², per axis) allowed away from the prediction."""
    motion_prior_gate: float = Field(default=1000.0, gt=0.0)
    """The prior is dropped for a frame whose PnP estimate and prediction disagree by more than this squared
    Mahalanobis distance (a collision or a slip, not noise)."""
    planar_motion: bool = True
    """Ground robot: the camera's base stays on the floor plane (height, roll and pitch of the first frame), only
    x, y and yaw change: the pose refinement solves for those three, loop transforms are projected (RTAB-Map
    Reg/Force3DoF). Needs the camera's mounting T_base_camera (the node takes it from tf_static, simulator
    exports from base_camera.txt); without it (TUM folders, hand-held cameras) it does nothing."""
    use_prior: bool = True
    """Use a per-frame prior pose (wheel odometry) as motion prediction and as fallback when lost."""
    keyframe_min_translation: float = Field(default=0.05, ge=0.0)
    """A keyframe for weak tracking (inlier ratio, ``keyframe_min_tracked``) needs at least this much
    translation (metres) or ``keyframe_min_rotation_deg`` from the last one: keyframe spacing then does not
    shrink with the camera rate."""
    keyframe_min_rotation_deg: float = Field(default=3.0, ge=0.0)
    """See ``keyframe_min_translation`` (degrees)."""
    keyframe_min_tracked: int = Field(default=60, ge=0)
    """New keyframe when fewer landmarks than this are tracked, whatever the ratio: the map must stay dense
    enough to track the next frames."""
    window_keyframes: int = Field(default=6, ge=1)
    """Keyframes bundle-adjusted together (poses and landmarks) at each new keyframe; 1 disables the adjustment."""
    window_fixed_keyframes: int = Field(default=0, ge=0)
    """Keyframes that left the window kept in its adjustment, fixed, where they observe its landmarks (ORB-SLAM's
    fixed covisible keyframes): the landmarks stay tied to where earlier keyframes saw them, so the window's
    oldest keyframe is not the only anchor. 0 = off (the default). Used only where no wheel prior ties the window
    (decided at each adjustment from its keyframes: a wheel-odometry prior between every consecutive pair turns
    it off), so a ground robot's results do not change, to the bit. Without wheels, the window's oldest keyframe
    is all that holds it, and at 320×240 on the procedural hall (30-60 tracked landmarks, a keyframe every few
    frames) the heading random-walks by 0.2° per keyframe. Measured with 6 (benchmarks/slam_matrix.py --set
    odometry.window_fixed_keyframes=6), procedural hall, 320×240, hand-held: survey 3.5/3.2/7.4/4.5 →
    2.5/2.7/3.9/3.0 cm at 5/10/15/30 Hz, figure eight 3.2/2.1/3.0/5.5 → 3.8/2.6/3.1/4.9 cm (4 of the 8 cells
    within 3 cm instead of 2), loop_revisit 2.7/1.8/2.4 → 2.9/1.8/2.1 cm at 5/10/30 Hz; 640×480 hand-held survey
    2.2/2.9 → 2.5/1.7 cm at 5/10 Hz. Before the wheel-prior rule it cost the ground robot up to 0.24 cm (survey at
    5 Hz 1.09 → 1.27 cm, figure eight at 10 Hz 1.03 → 1.27 cm, loop_revisit at 5 Hz 1.27 → 1.50 cm). With
    ``match_ratio=0.95`` as well, see there. Not the default: no setting tried beat the defaults on every cell."""
    window_iterations: int = Field(default=5, ge=1)
    """Levenberg–Marquardt iterations of the window's adjustment."""
    pixel_std: float = Field(default=1.0, gt=0.0)
    """Standard deviation of a keypoint's position on the finest pyramid level (pixels); a level's pixel size
    multiplies it."""
    depth_noise: float = Field(default=1.5e-3, ge=0.0)
    """Depth standard deviation per metre squared, σ(z) = depth_noise·z² + 1 mm (a Kinect v1: 1.43e-3,
    Khoshelham & Elberink 2012): weighs the depth residuals against the reprojections."""
    wheel_drift: float = Field(default=0.01, ge=0.0)
    """Relative standard deviation of the wheel odometry's motion between keyframes (per metre and per radian):
    weighs the wheels against the camera in the window's adjustment (0: the wheels only predict). 1 %: calibrated
    on the simulated robot's wheels (over keyframe steps of 25 cm their error is 3-4 mm RMS, mostly along the
    track, and error/σ has an RMS of 0.9-1.2; turns slip 1.3-1.7 %, one way for a whole turn). 3 %, the former
    default, over-stated the wheels' error twice and let the camera's heading drift through: on the photographic
    survey at 320×240 and 5 Hz, ATE 2.30 → 1.90 cm (docs/slam.md)."""
    triangulate: bool = True
    """Keypoints the depth camera did not measure (beyond its range, on edges) become landmarks when the next
    keyframe sees them again from a useful angle (epipolar search and triangulation, as ORB-SLAM): far texture
    holds the heading where measured points are few."""
    far_landmarks: bool = True
    """A keyframe's keypoints without depth that it neither tracked nor triangulated become landmarks at once, as
    *bearings*: on their rays at 2·``max_depth`` with a weak inverse-depth prior from the keyframe's centre
    (Civera et al.'s inverse-depth points; ORB-SLAM2 uses far stereo points as monocular ones). Landmark fusion
    gives them the later keyframes' observations, and the window's adjustment uses their reprojections (their
    distance free, held only by the prior and the parallax): far texture holds the window's heading from the first
    keyframe on, where a hall's measured points are mostly floor. Tracking matches only landmarks of known distance:
    a bearing becomes one when the epipolar triangulation (``triangulate``) finds it, when a keyframe measures its
    depth, or when the adjustment has narrowed its distance as far as a triangulation at ``min_parallax_deg`` would.
    Not where the wheels measure the motion (they hold the heading: a ground robot's results do not change, to the
    bit). The landmarks placed from bearings are not counted by the keyframe rules (counted, fewer keyframes were
    made and fewer loops closed, as with ``triangulation_keyframes``). Without its guards (``bearing_edge_radius``,
    ``bearing_fusion_radius``) it did not beat the camera alone (6 of the procedural hall's 12 hand-held 320×240
    cells better, 6 worse); with them, and the window stepping bearings in inverse depth (the defaults, 26 November
    2026, benchmarks/slam_matrix.py, all 48 hand-held cells against the camera alone): 46 of 48 within 3 cm instead
    of 45 (the procedural survey at 10/15 Hz 3.52/4.72 → 2.08/3.04 cm, the figure eight at 30 Hz 4.92 → 4.60), the
    mean 1.44 → 1.35 cm, the median 1.39 → 1.29 cm, 25 cells better and 23 worse (figures per cell in
    docs/slam.md); tracking's time unchanged, local mapping 36–72 ms per keyframe instead of 10–50. The other designs
    tried were worse (docs/slam.md, the table of settings tried on the hand-held cells)."""
    bearing_inverse_depth_std: float = Field(default=0.5, gt=0.0)
    """Standard deviation (1/m) of a bearing's inverse-distance prior (``far_landmarks``), about the mean
    1/(2·``max_depth``). Wide: where the prior is as narrow as the interval beyond the sensor (1/(2·``max_depth``)),
    it held the distances of points 5-8 m away at 12 m and the parallax they lacked turned the heading instead
    (survey at 15 Hz, odometry alone: 6.2 → 9.0 cm); 0.5 let the parallax decide (3.2 cm; 2: 4.4 cm)."""
    bearing_edge_radius: int = Field(default=4, ge=0)
    """A keypoint without depth becomes a bearing (``far_landmarks``) only where no pixel within this many of it has
    a depth either: a hole at a nearer surface's border (the sensor drops both sides of a depth edge) is not a
    point beyond the range; such a keypoint stays a candidate of the epipolar triangulation only. 0: every keypoint
    without depth. Measured on the procedural figure eight, hand-held, 320×240, 10 Hz (docs/slam.md, "Why the
    bearings made the figure eight worse"): half of the bearings the true poses place are nearer than the sensor's
    range; 4 px: 3.53 → 2.86 cm, with ``bearing_fusion_radius=80`` and ``bearing_fusion_ratio=0.7`` 2.09 cm."""
    bearing_fusion_radius: float = Field(default=80.0, ge=0.0)
    """Pixels around a bearing's projection (``far_landmarks``) within which the keypoint the landmark fusion gives
    it must be the clearly closest descriptor (``bearing_fusion_ratio``): its distance is a guess, so the keypoint at
    its projection may be a repeat of its texture (stripes, grout lines) while the true one lies elsewhere along its
    epipolar line. 0: no such test. Figure eight at 10 Hz: 40 px 2.59 cm, 80 px (ratio 0.7) with
    ``bearing_edge_radius=4`` 2.09 cm, against 3.53 without; it costs local mapping a search per bearing, on a
    grid of cells (there, ~5 ms a keyframe)."""
    bearing_fusion_ratio: float = Field(default=0.7, gt=0.0, le=1.0)
    """Largest ratio of the best to the second-best descriptor distance within ``bearing_fusion_radius``."""
    min_parallax_deg: float = Field(default=1.0, gt=0.0)
    """Smallest angle between the two rays of a triangulated landmark (smaller: its depth is too uncertain)."""
    triangulation_keyframes: int = Field(default=1, ge=1)
    """How many of the window's newest keyframes a new keyframe's keypoints without depth are searched in for
    triangulation, the oldest of them first (the longest baseline, the widest angle; ORB-SLAM searches its
    covisible keyframes). 1 = the previous keyframe only (the default). Ahead of a camera moving forward, far
    texture is seen under a few tenths of a degree from the previous keyframe, 25 cm back, and goes
    untriangulated. Searching the whole window (6), measured on the matrix (benchmarks/slam_matrix.py --set
    odometry.triangulation_keyframes=6), procedural hall, hand-held: at 320×240 the odometry drifts less (survey
    3.5/3.2/7.4/4.5 → 1.7/3.5/3.6/3.1 cm at 5/10/15/30 Hz; figure-eight odometry 7.5/9.6/6.6/6.5 →
    4.9/6.1/6.2/7.1 cm), but with more landmarks tracked fewer keyframes are made (222 → 130 at 5 Hz), fewer loops
    close on the figure eight (4/6/10/8 → 0/1/1/1) and its ATE gets worse (3.2/2.1/3.0/5.5 → 4.9/3.1/2.9/6.0 cm);
    at 640×480 the survey goes 2.2/2.9 → 2.9/2.6 cm at 5/10 Hz and tracking at 5 Hz, where most frames are
    keyframes, costs 19 → 23 ms of CPU per frame. Together with ``window_fixed_keyframes=6`` it was worse than
    that alone (hand-held 320×240: none of the 8 cells within 3 cm). Hence not the default."""
    surface_samples: int = Field(default=3000, ge=0)
    """Depth samples per frame for the point-to-plane term against a keyframe's surface (``surface_reach``), refined
    together with the features (the hybrid RGB-D odometry of DVO or Open3D; :mod:`~fleetslam.slam.surface_alignment`):
    where texture is poor (a grey wall, a plain floor, a small image) the room's geometry holds the pose. 0 = off.
    On the matrix's feature-poor cells (procedural hall, 320×240, hand-held) it took the ATE from 5.8-6.0 cm to
    2.1-3.2 cm; where features are plenty it changes little (±0.4 cm)."""
    surface_std_scale: float = Field(default=1.0, gt=0.0)
    """Multiplies the depth noise σ(z) as the point-to-plane residuals' standard deviation (1: the sensor's own;
    larger trusts the geometry less; 2 and 3 were tried and gave more drift on the feature-poor cells)."""
    surface_reach: float = Field(default=0.5, ge=0.0)
    """The point-to-plane term aligns each frame with the surface of the window's oldest keyframe within this
    distance (metres) and ``surface_reach_deg`` of the frame (the newest keyframe where none is): aligned with the
    newest keyframe only, it started again from that keyframe's own error at every keyframe, and in weak texture
    (a keyframe every two or three frames) those errors add up as a random walk of the heading. 0: the newest
    keyframe only (the behaviour before 27 November 2026; docs/slam.md gives the matrix with both)."""
    surface_reach_deg: float = Field(default=20.0, ge=0.0)
    """See ``surface_reach`` (degrees)."""
    photometric_samples: int = Field(default=0, ge=0)
    """Pixels of the newest keyframe compared by intensity with each frame (the strongest gradient of each block
    of the image's level nearest 320 pixels wide; :mod:`~fleetslam.slam.photometric_alignment`), refined together
    with the features and the surface: edges that are not corners (tile joints, rails, stripes) hold the pose along
    a plain floor or wall, where the surface term does not see. 0 = off (the default). Measured with 1500 on the
    matrix (benchmarks/slam_matrix.py --set odometry.photometric_samples=1500): at 320×240 it brought the
    procedural hall and the photographic survey from 23 to 26 cells of 32 within target (every ground-robot cell,
    e.g. the plant loop at 10 Hz 1.08 → 0.73 cm), at about 2 ms per frame; at 640×480 it made the hand-held camera
    on the procedural survey worse (2.2 → 3.3 cm at 5 Hz, 2.9 → 4.0 cm at 10 Hz) and cost 4 ms per frame. A
    camera of 320×240 or less in a texture-poor place gains from it; off by default until it helps everywhere.
    """
    photometric_std: float = Field(default=8.0, gt=0.0)
    """Standard deviation of one intensity residual (grey levels): the sensor's noise and what the model leaves
    out (view-dependent shading, interpolation, correlated neighbours)."""
    photometric_blur: float = Field(default=2.0, ge=0.0)
    """Gaussian smoothing (σ, pixels of a 640-pixel-wide image, scaled with the width) of both images: a wider
    basin of convergence than the raw pixels' one."""
    photometric_min_gradient: float = Field(default=4.0, ge=0.0)
    """A block's strongest gradient (grey levels per pixel, after smoothing) must reach this to be compared:
    flat blocks constrain nothing and only add noise."""
    coast_distance: float = Field(default=1.5, gt=0.0)
    """Metres followed on the wheel odometry without matching the map before the map restarts there."""
    lost_frames: int = Field(default=3, ge=1)
    """Without wheel odometry, frames that fail to track before the map restarts (the pipeline relocalises)."""


class BackendConfig(ConfigModel):
    """GTSAM pose graph."""

    robust_kernel: Literal["none", "huber", "cauchy"] = "huber"
    """Robust kernel on loop-closure constraints."""

    robust_parameter: float = Field(default=1.345, gt=0.0)
    """Kernel width (in standard deviations)."""

    optimize_max_error: float = Field(default=3.0, ge=0.0)
    """Reject a loop closure if, after optimisation, a constraint's translational error exceeds this factor
    of its expected standard deviation (RTAB-Map RGBD/OptimizeMaxError; 0 disables)."""

    odometry_translation_std: float = Field(default=0.005, gt=0.0)
    """Standard deviation of odometry translation between keyframes (metres; measured on the simulated plant:
    a few millimetres with the motion prior and planar motion)."""

    odometry_rotation_std_deg: float = Field(default=0.2, gt=0.0)
    """Standard deviation of odometry rotation between keyframes (degrees)."""

    loop_translation_std: float = Field(default=0.02, gt=0.0)
    """Standard deviation of loop-closure translation (metres)."""

    loop_rotation_std_deg: float = Field(default=1.0, gt=0.0)
    """Standard deviation of loop-closure rotation (degrees)."""


class SlamConfig(ConfigModel):
    """RGB-D graph SLAM, RTAB-Map style."""

    features: FeatureConfig = Field(default_factory=FeatureConfig)
    """Keypoints and descriptors."""

    odometry: OdometryConfig = Field(default_factory=OdometryConfig)
    """Odometry front-end (``kind``) and the visual odometry's parameters."""

    backend: BackendConfig = Field(default_factory=BackendConfig)
    """Pose-graph optimisation."""

    loop_closure: LoopClosureConfig = Field(default_factory=lambda: LoopClosureConfig.model_validate({}))
    """Appearance-based loop-closure detection."""

    memory: MemoryConfig = Field(default_factory=lambda: MemoryConfig.model_validate({}))
    """STM/WM/LTM memory management."""

    loop_closure_enabled: bool = True
    """Detect loop closures (off: odometry and pose graph only)."""

    relocalization_candidates: int = Field(default=10, ge=0)
    """When tracking is lost, verify the frame against this many most recent locations in memory and
    continue from the first that passes PnP verification (0 = never; the odometry then follows the wheel
    prior or constant velocity and restarts its local map where it is)."""
