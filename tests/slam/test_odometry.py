from __future__ import annotations

import numpy as np
import pytest

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle
from fleetslam.slam.config import OdometryConfig
from fleetslam.slam.odometry import LocalMap, VisualOdometry

from .textured_room import make_textures, render

INTRINSICS = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
#: looking into a corner of the room from 2-3 m (a Kinect's best range), so that the scene has depth (a single
#: wall is nearly planar; from 4-5 m a small yaw and a sideways shift look alike and the pair is ill-posed).
BASE = pose_from_xyz_rpy(0.5, 0.3, 0.5, 0.0, np.radians(45.0), 0.0)


@pytest.fixture(scope="module")
def textures() -> list[np.ndarray]:
    return make_textures(np.random.default_rng(0))


@pytest.mark.parametrize(
    "motion",
    [
        pose_from_xyz_rpy(0.02, 0.0, 0.0, 0.0, 0.0, 0.0),
        pose_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, np.radians(1.0), 0.0),
        pose_from_xyz_rpy(0.03, 0.01, 0.02, np.radians(1.0), np.radians(2.0), 0.0),
    ],
)
def test_odometry_recovers_known_motion(textures: list[np.ndarray], motion: np.ndarray) -> None:
    # A jump from standstill within one frame: no motion prior (it models a ground robot's smooth motion).
    vo = VisualOdometry(OdometryConfig(motion_prior_acceleration=0.0), INTRINSICS)
    first = vo.track(*render(BASE, INTRINSICS, textures), 0.0)
    assert first.is_keyframe and not first.lost
    result = vo.track(*render(BASE @ motion, INTRINSICS, textures), 0.033)
    # ~700 of 1000 keypoints re-detect and match (545 the fewest over 30 motions × 3 SIMD paths); 100 is the
    # floor below which PnP on one pair stops being well determined.
    assert not result.lost and result.inliers > 100
    error = invert(motion) @ result.pose
    # One frame pair, no map: ORB keypoints re-detect with ~0.6 px scatter (pixel quantisation per pyramid
    # level), correlated within a texture blob, so PnP is good to a few mm and a tenth of a degree. Worst over 30
    # random motions × 3 numpy/OpenCV SIMD paths: 5.3 mm, 0.12°; the bounds are about twice that.
    assert np.linalg.norm(error[:3, 3]) < 0.010
    assert np.degrees(rotation_angle(error)) < 0.25


def test_a_blank_view_coasts_on_the_wheels_and_tracking_resumes_on_the_same_map(textures: list[np.ndarray]) -> None:
    vo = VisualOdometry(OdometryConfig(), INTRINSICS)
    rgb, depth = render(BASE, INTRINSICS, textures)
    vo.track(rgb, depth, 0.0, prior=np.eye(4))
    step = pose_from_xyz_rpy(0.05, 0.0, 0.0, 0.0, 0.0, 0.0)
    blank = np.full_like(rgb, 128)  # a texture-less wall
    result = vo.track(blank, depth, 0.1, prior=step)
    assert result.coasting and not result.lost
    np.testing.assert_allclose(result.pose, step, atol=1e-9)  # the wheels' pose itself, up to round-off
    # The map was kept: the next textured frame tracks on it at once, no restart.
    after = vo.track(*render(BASE @ step, INTRINSICS, textures), 0.2, prior=step)
    assert not after.lost and not after.coasting and not after.map_restarted and after.inliers > 100
    # The same view as the map's own keyframe, 5 cm on: a few millimetres (the pair test's bound).
    assert np.linalg.norm(after.pose[:3, 3] - step[:3, 3]) < 0.010


def test_without_wheels_a_blank_stretch_is_lost_and_the_map_restarts(textures: list[np.ndarray]) -> None:
    config = OdometryConfig()
    vo = VisualOdometry(config, INTRINSICS)
    rgb, depth = render(BASE, INTRINSICS, textures)
    vo.track(rgb, depth, 0.0)
    blank = np.full_like(rgb, 128)
    results = [vo.track(blank, depth, 0.1 * (k + 1)) for k in range(config.lost_frames)]
    assert all(r.lost for r in results)
    assert not any(r.map_restarted for r in results[:-1]) and results[-1].map_restarted


def test_local_mapping_after_the_pose_gives_the_same_track_whenever_it_runs(textures: list[np.ndarray]) -> None:
    """The window's adjustment runs after a keyframe's pose is out (``local_mapping``), or at the start of the
    next frame when the caller did not run it: the same poses either way."""
    frames = [
        (render(BASE @ pose_from_xyz_rpy(0.06 * k, 0.0, 0.01 * k, 0.0, np.radians(2.0 * k), 0.0), INTRINSICS,
                textures), 0.1 * k)
        for k in range(6)
    ]  # fmt: skip
    explicit, implicit = VisualOdometry(OdometryConfig(), INTRINSICS), VisualOdometry(OdometryConfig(), INTRINSICS)
    adjusted = 0
    for (rgb, depth), stamp in frames:
        first = explicit.track(rgb, depth, stamp)
        second = implicit.track(rgb, depth, stamp)
        np.testing.assert_array_equal(first.pose, second.pose)
        after = explicit.local_mapping()
        if after is not None:
            adjusted += 1
            assert first.is_keyframe
            # The adjustment moves the keyframe by what its window's errors were: a millimetre or less here.
            assert np.linalg.norm(after[:3, 3] - first.pose[:3, 3]) < 0.005
    assert adjusted >= 1  # 6 cm and 2° per frame: a keyframe after 25 cm, with a window to adjust
    assert explicit.local_mapping() is None  # nothing left pending


def test_with_the_photometric_term_the_known_motion_is_recovered_as_well(textures: list[np.ndarray]) -> None:
    """The photometric term (off by default) on a 640×480 camera: it works on the 320×240 level and changes the
    pair's result within the feature-only bounds."""
    config = OdometryConfig(motion_prior_acceleration=0.0, photometric_samples=1500)
    vo = VisualOdometry(config, INTRINSICS)
    motion = pose_from_xyz_rpy(0.03, 0.01, 0.02, np.radians(1.0), np.radians(2.0), 0.0)
    vo.track(*render(BASE, INTRINSICS, textures), 0.0)
    assert vo.window[-1].intensity is not None and len(vo.window[-1].intensity.points) > 500  # 833 measured
    result = vo.track(*render(BASE @ motion, INTRINSICS, textures), 0.033)
    error = invert(motion) @ result.pose
    # The bounds of the feature-only pair test (0.1 mm, 0.003° measured; 0.2 mm, 0.008° without the term).
    assert not result.lost and np.linalg.norm(error[:3, 3]) < 0.010
    assert np.degrees(rotation_angle(error)) < 0.25


def test_far_texture_is_triangulated_with_an_older_keyframe_of_the_window(textures: list[np.ndarray]) -> None:
    """Walking towards texture the depth camera does not reach, neighbouring keyframes see it under too small an
    angle; the window's older keyframes, farther back along the path, see it under a wide one: its keypoints
    become landmarks on the room's walls."""
    # Keyframes 8 cm apart, the walls 2-3 m ahead: under 1° between neighbours for texture up to 30° off the
    # path, under the 2° asked for, which a keyframe three or more back gives.
    # Triangulation alone: bearings (far_landmarks) would place the same keypoints at once, beyond the range.
    config = OdometryConfig(
        keyframe_translation=0.07, min_parallax_deg=2.0, triangulation_keyframes=6, far_landmarks=False
    )
    vo = VisualOdometry(config, INTRINSICS)
    for k in range(8):
        rgb, depth = render(BASE @ pose_from_xyz_rpy(0.0, 0.0, 0.08 * k, 0.0, 0.0, 0.0), INTRINSICS, textures)
        depth[: INTRINSICS.height // 2] = 0.0  # the upper half beyond the depth camera's range
        result = vo.track(rgb, depth, 0.1 * k)
        assert not result.lost
        vo.local_mapping()
    observed = np.concatenate([kf.landmarks[kf.depths == 0.0] for kf in vo.window])
    rows, found = vo.local_map.rows(np.unique(observed))
    # The odometry's frame is the first camera's.
    points = vo.local_map.points[rows[found]] @ BASE[:3, :3].T + BASE[:3, 3]
    assert len(points) > 50  # 0 with the default, the previous keyframe only (142 measured)
    # On the room's walls (the box's faces at ±2.5 m), as far as 2-5° of parallax tell depth: ~1.3 mrad of keypoint
    # noise over 35-90 mrad, 1.5-4 % of 2.5 m (measured: median 8 cm, 75 % within 19 cm; a tenth, matches of
    # look-alike shapes along the epipolar line, are metres off).
    off_wall = np.abs(np.abs(points).max(axis=1) - 2.5)
    assert np.median(off_wall) < 0.12 and np.percentile(off_wall, 75) < 0.3


def test_keyframes_that_left_the_window_stay_fixed_in_its_adjustment(textures: list[np.ndarray]) -> None:
    """With ``window_fixed_keyframes`` the keyframes that left the window join its adjustment where they see its
    landmarks, held where they are; the track stays as accurate as the pair test's."""
    config = OdometryConfig(window_keyframes=3, window_fixed_keyframes=3, keyframe_translation=0.05)
    vo = VisualOdometry(config, INTRINSICS)
    motions = [pose_from_xyz_rpy(0.03 * k, 0.0, 0.01 * k, 0.0, np.radians(1.0 * k), 0.0) for k in range(9)]
    retired_seen = 0
    for k, motion in enumerate(motions):
        result = vo.track(*render(BASE @ motion, INTRINSICS, textures), 0.1 * k)
        assert not result.lost
        # Local mapping makes the keyframe, which may push the window's oldest out: held from then on too.
        before = {id(kf): kf.pose.copy() for kf in [*vo._retired, *vo.window]}
        if vo.local_mapping() is not None and vo._retired:
            retired_seen += 1
            for kf in vo._retired:
                np.testing.assert_allclose(kf.pose, before[id(kf)], atol=1e-12)
    assert retired_seen >= 2 and len(vo._retired) >= 2
    # The odometry's frame is the first camera's: the last pose is the last motion, to the pair test's bounds.
    error = invert(motions[-1]) @ vo.pose
    assert np.linalg.norm(error[:3, 3]) < 0.010 and np.degrees(rotation_angle(error)) < 0.25


def test_the_fixed_keyframes_hold_the_window_only_where_no_wheel_prior_ties_it(textures: list[np.ndarray]) -> None:
    """The retired keyframes join the window's adjustment for a camera without wheels; with the wheels tying each
    keyframe to the one before, the adjustment is the one without them, to the bit."""
    motions = [pose_from_xyz_rpy(0.03 * k, 0.0, 0.01 * k, 0.0, np.radians(1.0 * k), 0.0) for k in range(9)]
    frames = [render(BASE @ motion, INTRINSICS, textures) for motion in motions]

    def track(fixed: int, wheels: bool) -> tuple[VisualOdometry, list[np.ndarray]]:
        config = OdometryConfig(window_keyframes=3, window_fixed_keyframes=fixed, keyframe_translation=0.05)
        vo = VisualOdometry(config, INTRINSICS)
        poses = []
        for k, ((rgb, depth), motion) in enumerate(zip(frames, motions, strict=True)):
            poses.append(vo.track(rgb, depth, 0.1 * k, prior=motion if wheels else None).pose)
            poses.append(adjusted if (adjusted := vo.local_mapping()) is not None else poses[-1])
        return vo, poses

    with_wheels, with_wheels_poses = track(3, wheels=True)
    assert len(with_wheels._retired) >= 2 and not with_wheels._needs_fixed_keyframes()
    for a, b in zip(with_wheels_poses, track(0, wheels=True)[1], strict=True):
        np.testing.assert_array_equal(a, b)
    hand_held, hand_held_poses = track(3, wheels=False)
    assert len(hand_held._retired) >= 2 and hand_held._needs_fixed_keyframes()
    plain = track(0, wheels=False)[1]
    assert any(not np.array_equal(a, b) for a, b in zip(hand_held_poses, plain, strict=True))


def test_keypoints_without_depth_become_bearings_for_the_window_only_without_wheels(
    textures: list[np.ndarray],
) -> None:
    """With ``far_landmarks`` a keyframe's keypoints beyond the depth camera's range become landmarks at once,
    anchored (their distance the prior's); tracking never matches one whose distance is unknown, the window's
    adjustment narrows it, and with the wheels none is made: the track is the one without, to the bit."""
    motions = [pose_from_xyz_rpy(0.0, 0.0, 0.08 * k, 0.0, 0.0, 0.0) for k in range(6)]
    frames = []
    for motion in motions:
        rgb, depth = render(BASE @ motion, INTRINSICS, textures)
        depth[: INTRINSICS.height // 2] = 0.0  # the upper half beyond the depth camera's range
        frames.append((rgb, depth))

    def track(far: bool, wheels: bool) -> tuple[VisualOdometry, list[np.ndarray]]:
        vo = VisualOdometry(OdometryConfig(far_landmarks=far, keyframe_translation=0.07), INTRINSICS)
        poses = []
        for k, ((rgb, depth), motion) in enumerate(zip(frames, motions, strict=True)):
            result = vo.track(rgb, depth, 0.1 * k, prior=motion if wheels else None)
            assert not result.lost
            poses.append(result.pose)
            vo.local_mapping()
        return vo, poses

    vo, poses = track(far=True, wheels=False)
    anchored = ~np.isnan(vo.local_map.anchors[:, 0])
    assert anchored.sum() > 100
    # Each is anchored at the camera centre of the keyframe that made it (as it was then: the adjustment moves the
    # keyframes by millimetres).
    centres = np.stack([kf.pose[:3, 3] for kf in vo.window])
    gap = np.linalg.norm(vo.local_map.anchors[anchored, None, :3] - centres[None], axis=2).min(axis=1)
    assert np.all(gap < 0.01)
    # The adjustment narrowed the distance of those the window saw twice: below the prior's deviation.
    assert np.any(vo.local_map.anchors[anchored, 3] < vo.config.bearing_inverse_depth_std)
    # The walls are 2-3 m away: the pose still follows the motion, to the pair test's bounds.
    error = invert(motions[-1]) @ poses[-1]
    assert np.linalg.norm(error[:3, 3]) < 0.010 and np.degrees(rotation_angle(error)) < 0.25

    with_wheels, wheel_poses = track(far=True, wheels=True)
    assert np.isnan(with_wheels.local_map.anchors[:, 0]).all()
    for a, b in zip(wheel_poses, track(far=False, wheels=True)[1], strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_bearing_merged_with_a_measured_landmark_takes_its_position() -> None:
    """Fusion keeps the landmark with more observations; where that is a bearing (its distance a guess) and the
    other was measured, the one kept takes the measured position and is a bearing no more."""
    local_map = LocalMap(100)
    descriptors = np.zeros((2, 32), np.uint8)
    measured = local_map.add(np.array([[0.0, 0.0, 3.0], [1.0, 0.0, 3.0]]), descriptors)
    bearings = local_map.add(
        np.array([[0.0, 0.0, 12.0], [1.0, 0.0, 12.0]]), descriptors, anchor=np.array([0, 0, 0, 0.5])
    )
    other = local_map.add(np.array([[2.0, 0.0, 12.0]]), descriptors[:1], anchor=np.array([0, 0, 0, 0.5]))
    local_map.merge(measured[:1], bearings[:1])  # a measured landmark into a bearing
    local_map.merge(other, bearings[1:])  # a bearing into a bearing: still one
    rows, found = local_map.rows(np.concatenate([measured, bearings, other]))
    assert found.tolist() == [False, True, True, True, False]
    np.testing.assert_array_equal(local_map.points[rows[2]], [0.0, 0.0, 3.0])
    assert np.isnan(local_map.anchors[rows[2]]).all()
    np.testing.assert_array_equal(local_map.points[rows[3]], [1.0, 0.0, 12.0])
    assert not np.isnan(local_map.anchors[rows[3]]).any()


def test_keypoints_next_to_measured_depth_do_not_become_bearings(textures: list[np.ndarray]) -> None:
    """A keypoint without depth within ``bearing_edge_radius`` pixels of one with depth sits on a hole or a nearer
    surface's border, not beyond the range: it does not become a bearing (the others still do)."""
    rgb, depth = render(BASE, INTRINSICS, textures)
    edge = INTRINSICS.height // 2
    depth[:edge] = 0.0  # the upper half beyond the depth camera's range

    def bearing_rows(radius: int) -> np.ndarray:
        vo = VisualOdometry(OdometryConfig(far_landmarks=True, bearing_edge_radius=radius), INTRINSICS)
        vo.track(rgb, depth, 0.0)
        vo.local_mapping()
        keyframe = vo.window[-1]
        rows, found = vo.local_map.rows(keyframe.landmarks)
        anchored = found & ~np.isnan(vo.local_map.anchors[rows, 0])
        return keyframe.pixels[anchored, 1]

    every = bearing_rows(0)
    assert len(every) > 50 and np.any(every > edge - 6)
    kept = bearing_rows(6)
    assert len(kept) > 50 and np.all(np.rint(kept) < edge - 6)


def test_the_surface_term_aligns_with_the_oldest_keyframe_within_reach(textures: list[np.ndarray]) -> None:
    """Aligned with the newest keyframe only, the point-to-plane term would start again from that keyframe's error
    at every keyframe; it takes the oldest of the window within ``surface_reach`` / ``surface_reach_deg``."""
    config = OdometryConfig(keyframe_translation=0.07, window_keyframes=6)
    vo = VisualOdometry(config, INTRINSICS)
    for k in range(8):  # keyframes 8 cm apart along the camera's axis: the window keeps the last six
        result = vo.track(*render(BASE @ pose_from_xyz_rpy(0.0, 0.0, 0.08 * k, 0.0, 0.0, 0.0), INTRINSICS, textures),
                          0.1 * k)  # fmt: skip
        assert result.is_keyframe and not result.lost
        vo.local_mapping()
    window = list(vo.window)
    distances = [float(np.linalg.norm(kf.pose[:3, 3])) for kf in window]
    np.testing.assert_allclose(distances, [0.16, 0.24, 0.32, 0.40, 0.48, 0.56], atol=0.01)

    def reference(z: float, yaw_deg: float = 0.0, **overrides: float) -> int:
        vo.config = config.model_copy(update=overrides)
        start = pose_from_xyz_rpy(0.0, 0.0, z, 0.0, np.radians(yaw_deg), 0.0)
        chosen = vo._surface_keyframe(start)
        return next(i for i, kf in enumerate(window) if kf is chosen)

    assert reference(0.64) == 0  # 0.48 m from the oldest
    assert reference(0.75) == 2  # 0.59 and 0.51 m from the two oldest: beyond 0.5 m
    assert reference(0.75, surface_reach=0.3) == 4
    assert reference(0.64, yaw_deg=25.0) == 5  # turned beyond 20° from every keyframe: the newest
    assert reference(0.64, surface_reach=0.0) == 5  # 0: the newest only
