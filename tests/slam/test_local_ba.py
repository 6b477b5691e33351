"""Windowed RGB-D bundle adjustment on synthetic keyframes: poses and points, priors, the planar subspace."""

from __future__ import annotations

import numpy as np

from fleetslam.geometry import T_BODY_OPTICAL, invert, make_pose, pose_from_planar, pose_from_xyz_rpy, rotation_angle
from fleetslam.slam.local_ba import BundleProblem, PosePrior, bundle_adjust
from fleetslam.slam.pose_refinement import planar_basis

K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


def _scene(
    rng: np.random.Generator, poses_wc: list[np.ndarray], points: np.ndarray | None = None, pixel_noise: float = 0.5
) -> BundleProblem:
    """World points (default: 2-5 m ahead of a camera looking along world z) seen from every pose, half of them
    per pose, with pixel noise and Kinect-like depth noise (σ = 1.5e-3·z²)."""
    if points is None:
        points = rng.uniform([-3.0, -1.5, 2.0], [3.0, 1.5, 5.0], (800, 3))
    obs_pose, obs_point, pixels, depths = [], [], [], []
    for k, pose in enumerate(poses_wc):
        T = invert(pose)
        cam = points @ T[:3, :3].T + T[:3, 3]
        uv = cam[:, :2] / cam[:, 2:3] * 525.0 + [319.5, 239.5]
        seen = (cam[:, 2] > 0.3) & np.all((uv > 0) & (uv < [640, 480]), axis=1) & (rng.random(len(points)) < 0.5)
        index = np.flatnonzero(seen)
        obs_pose += [k] * len(index)
        obs_point += index.tolist()
        pixels.append(uv[index] + rng.normal(0.0, pixel_noise, (len(index), 2)))
        depths.append(cam[index, 2] * (1.0 + rng.normal(0.0, 1.5e-3, len(index)) * cam[index, 2]))
    return BundleProblem(
        poses=np.stack([invert(p) for p in poses_wc]),
        points=points,
        obs_pose=np.asarray(obs_pose, np.intp),
        obs_point=np.asarray(obs_point, np.intp),
        pixels=np.vstack(pixels),
        depths=np.concatenate(depths),
        pixel_std=np.full(len(obs_pose), pixel_noise),
        camera_matrix=K,
        fixed=np.arange(len(poses_wc)) == 0,
    )


def _position_errors(poses_cw: np.ndarray, truth_wc: list[np.ndarray]) -> np.ndarray:
    return np.array([np.linalg.norm(invert(p)[:3, 3] - t[:3, 3]) for p, t in zip(poses_cw, truth_wc, strict=True)])


def test_window_recovers_perturbed_poses_and_points() -> None:
    rng = np.random.default_rng(0)
    truth = [pose_from_xyz_rpy(0.1 * k, 0.0, 0.05 * k, 0.0, np.radians(2.0 * k), 0.0) for k in range(6)]
    problem = _scene(rng, truth)
    true_points = problem.points.copy()
    for k in range(1, 6):  # 2 cm / 0.6° off, the points 3 cm off: what one frame's error does to a map
        problem.poses[k] = pose_from_xyz_rpy(*rng.normal(0, 0.02, 3), *rng.normal(0, 0.01, 3)) @ problem.poses[k]
    problem.points = problem.points + rng.normal(0.0, 0.03, problem.points.shape)
    before = _position_errors(problem.poses, truth)
    result = bundle_adjust(problem)
    after = _position_errors(result.poses, truth)
    assert before.max() > 0.02
    # ~250 points per view, their depth σ 2 cm at 2-5 m: each pose to ~1.3 mm (√250 averaging); the worst of
    # five measured 3.3 mm. Bound: 6σ.
    assert after.max() < 0.008, after
    seen = np.unique(problem.obs_point)
    # Depth noise 1.5e-3·z² at 2-5 m is 2.2 cm RMS per view; averaged over the views (1.7 cm measured) the points
    # are far better than the 5 cm they started with.
    rms = np.sqrt(np.mean(np.sum((result.points[seen] - true_points[seen]) ** 2, axis=1)))
    assert rms < 0.025
    assert result.final_cost < result.initial_cost and result.inliers.mean() > 0.99


def test_wrong_matches_are_flagged_and_do_not_pull_the_poses() -> None:
    rng = np.random.default_rng(1)
    truth = [pose_from_xyz_rpy(0.1 * k, 0.0, 0.0, 0.0, np.radians(1.5 * k), 0.0) for k in range(4)]
    problem = _scene(rng, truth)
    # A wrong match can only be told from a right one where other views of its point disagree with it: corrupt
    # 5 % of the observations of points seen three or more times, 20-40 px away.
    counts = np.bincount(problem.obs_point, minlength=len(problem.points))
    candidates = np.flatnonzero(counts[problem.obs_point] >= 3)
    wrong = rng.choice(candidates, size=len(problem.obs_pose) // 20, replace=False)
    problem.pixels[wrong] += rng.uniform(20.0, 40.0, (len(wrong), 2))
    result = bundle_adjust(problem)
    assert np.mean(~result.inliers[wrong]) > 0.95
    # Huber: the outliers pull only linearly (3.0 mm measured, as without them); bound as above.
    assert _position_errors(result.poses, truth).max() < 0.008


def test_pose_prior_places_a_keyframe_that_saw_nothing() -> None:
    truth_relative = pose_from_xyz_rpy(0.3, 0.0, 0.1, 0.0, 0.2, 0.0)  # camera 1 in camera 0
    problem = BundleProblem(
        poses=np.stack([np.eye(4), invert(pose_from_xyz_rpy(0.2, 0.05, 0.0, 0.0, 0.1, 0.0))]),
        points=np.zeros((0, 3)),
        obs_pose=np.zeros(0, np.intp),
        obs_point=np.zeros(0, np.intp),
        pixels=np.zeros((0, 2)),
        depths=np.zeros(0),
        pixel_std=np.zeros(0),
        camera_matrix=K,
        fixed=np.array([True, False]),
        priors=[PosePrior(0, 1, truth_relative, np.eye(6) * 1e4)],
    )
    result = bundle_adjust(problem, iterations=10)
    relative = result.poses[0] @ invert(result.poses[1])  # T_c0_c1 from T_cw poses
    # Only the linearisation of the prior's Jacobian stands between the start and the prior: converged exactly.
    assert np.linalg.norm(relative[:3, 3] - truth_relative[:3, 3]) < 1e-6
    assert rotation_angle(invert(relative) @ truth_relative) < 1e-6


def test_planar_subspace_keeps_the_base_on_the_floor() -> None:
    rng = np.random.default_rng(2)
    tilt = pose_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, np.radians(5.0), 0.0)
    base_camera = make_pose(tilt[:3, :3] @ T_BODY_OPTICAL[:3, :3], [0.1, 0.0, 0.5])
    bases = [pose_from_planar(0.15 * k, 0.02 * k, 0.05 * k) for k in range(5)]
    truth = [b @ base_camera for b in bases]
    points = rng.uniform([2.5, -2.0, 0.0], [6.0, 2.5, 2.5], (800, 3))  # ahead of the robot (base x)
    problem = _scene(rng, truth, points)
    problem.basis = planar_basis(base_camera)
    for k in range(1, 5):
        moved = pose_from_planar(0.15 * k + 0.02, 0.02 * k - 0.015, 0.05 * k + 0.01) @ base_camera
        problem.poses[k] = invert(moved)
    result = bundle_adjust(problem)
    for k in range(5):
        base = invert(result.poses[k]) @ invert(base_camera)  # T_world_base
        assert abs(base[2, 3]) < 1e-9 and abs(base[2, 2] - 1.0) < 1e-9  # still on the floor, level
        np.testing.assert_allclose(base[:2, 3], bases[k][:2, 3], atol=0.003)  # ~1 mm measured


def test_motion_only_refinement_leaves_the_points_alone() -> None:
    rng = np.random.default_rng(4)
    truth = [pose_from_xyz_rpy(0.05, 0.0, 0.02, 0.0, 0.03, 0.0)]
    problem = _scene(rng, truth)
    problem.fixed = np.array([False])
    problem.points_fixed = True
    start = pose_from_xyz_rpy(0.02, -0.01, 0.0, 0.0, 0.01, 0.0) @ problem.poses[0]
    problem.poses[0] = start
    points = problem.points.copy()
    result = bundle_adjust(problem)
    np.testing.assert_array_equal(result.points, points)
    assert _position_errors(result.poses, truth)[0] < 0.002  # ~400 observations: sub-millimetre


def _heading_errors(poses_cw: np.ndarray, truth_wc: list[np.ndarray]) -> np.ndarray:
    return np.degrees([rotation_angle(invert(p) @ invert(t)) for p, t in zip(poses_cw, truth_wc, strict=True)])


def test_far_points_without_depth_hold_the_heading_through_their_inverse_depth_prior() -> None:
    rng = np.random.default_rng(4)
    # A camera moving forward 8 cm per keyframe down a hall: a few measured points near it, many beyond the depth
    # camera's range (6-15 m) that it sees without depth.
    truth = [pose_from_xyz_rpy(0.0, 0.0, 0.08 * k, 0.0, 0.0, 0.0) for k in range(6)]
    near = rng.uniform([-2.0, 0.5, 1.5], [2.0, 1.2, 3.0], (24, 3))
    far = rng.uniform([-6.0, -2.0, 6.0], [6.0, 1.0, 15.0], (300, 3))
    problem = _scene(rng, truth, np.vstack([near, far]), pixel_noise=1.0)
    problem.depths[problem.obs_point >= len(near)] = 0.0
    for k in range(1, 6):  # the heading off by 0.3° more per keyframe: what a random walk leaves
        problem.poses[k] = pose_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, np.radians(0.3 * k), 0.0) @ problem.poses[k]
    # The far points start on their rays from the first keyframe, at the prior's mean distance (12 m).
    mean, std = 1.0 / 12.0, 0.5
    rays = far / np.linalg.norm(far, axis=1)[:, None]
    problem.points = np.vstack([near, rays / mean])
    anchors = np.full((len(problem.points), 3), np.nan)
    anchors[len(near) :] = 0.0
    with_prior = BundleProblem(**{**problem.__dict__, "point_anchors": anchors, "inverse_depth_prior": (mean, std)})
    keep = problem.obs_point < len(near)
    near_only = BundleProblem(
        **{
            **problem.__dict__,
            "points": near,
            "obs_pose": problem.obs_pose[keep],
            "obs_point": problem.obs_point[keep],
            "pixels": problem.pixels[keep],
            "depths": problem.depths[keep],
            "pixel_std": problem.pixel_std[keep],
        }
    )
    held = bundle_adjust(with_prior)
    alone = bundle_adjust(near_only)
    # The bearings pin the heading (measured: 0.06° at most); the 24 near points alone leave it loose (1.8°).
    assert _heading_errors(held.poses, truth).max() < 0.15
    assert _heading_errors(alone.poses, truth).max() > 0.5
    # Their inverse distances go where the parallax puts them, within what each point's own block of the normal
    # equations says (its inverse: the point's covariance, the poses held): measured, the error over its standard
    # deviation 0.44 at the median, 2.1 at the 90th percentile (σ 0.033 m⁻¹ at the median, the prior's 0.5).
    assert held.point_hessian.shape == (len(problem.points), 3, 3)
    offset = held.points[len(near) :]
    distance = np.linalg.norm(offset, axis=1)
    ray = offset / distance[:, None]
    covariance = np.linalg.inv(held.point_hessian[len(near) :] + 1e-9 * np.eye(3))
    inverse_std = np.sqrt(np.einsum("pi,pij,pj->p", ray, covariance, ray)) / distance**2
    z = np.abs(1.0 / distance - 1.0 / np.linalg.norm(far, axis=1)) / inverse_std
    assert np.median(z) < 1.0 and np.percentile(z, 90) < 3.0
    assert np.median(inverse_std) < 0.2 * std


def test_near_points_without_depth_reach_their_distance_in_the_windows_few_iterations() -> None:
    """Texture 2-4 m away that the depth camera missed (a dark or shiny wall), placed where the prior guesses
    (9 m): stepping in inverse depth, five iterations (the odometry's window) bring the points to their distances
    and leave the poses where they are, as if the points had started at their true distances."""
    rng = np.random.default_rng(7)
    truth = [pose_from_xyz_rpy(0.05 * k, 0.0, 0.08 * k, 0.0, 0.0, 0.0) for k in range(5)]
    near = rng.uniform([-1.5, -1.0, 2.0], [1.5, 1.0, 4.0], (300, 3))
    problem = _scene(rng, truth, near, pixel_noise=0.5)
    problem.depths[problem.obs_point >= 100] = 0.0  # two thirds without depth
    mean, std = 1.0 / 9.0, 0.5
    rays = near[100:] / np.linalg.norm(near[100:], axis=1)[:, None]
    problem.points = np.vstack([near[:100], rays / mean])
    anchors = np.full((len(near), 3), np.nan)
    anchors[100:] = 0.0
    problem.point_anchors, problem.inverse_depth_prior = anchors, (mean, std)
    result = bundle_adjust(problem, iterations=5)
    # Measured: 4.3 mm, as from the true distances; stepping in x, y, z the poses ended 92 mm off.
    assert _position_errors(result.poses, truth).max() < 0.01
    # Those seen from two keyframes or more (a point seen once has no parallax: it stays at the prior's guess).
    seen_twice = np.bincount(problem.obs_point, minlength=len(near))[100:] >= 2
    error = np.abs(np.linalg.norm(result.points[100:], axis=1) - np.linalg.norm(near[100:], axis=1))[seen_twice]
    # From 5-7 m off to a few centimetres (measured 5.3 cm: two-view parallax over ≤ 40 cm at 2-4 m, 0.5 px).
    assert np.median(error) < 0.1
    # Each point's block of the normal equations still comes back in x, y, z: its inverse along the ray is the
    # inverse distance's variance, far below the prior's.
    offset = result.points[100:]
    distance = np.linalg.norm(offset, axis=1)
    ray = offset / distance[:, None]
    covariance = np.linalg.inv(result.point_hessian[100:] + 1e-9 * np.eye(3))
    inverse_depth_std = np.sqrt(np.einsum("pi,pij,pj->p", ray, covariance, ray)) / distance**2
    assert np.median(inverse_depth_std) < 0.1 * std
