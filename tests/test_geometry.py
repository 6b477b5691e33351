import numpy as np
import pytest

from fleetslam import geometry as g


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)


def test_quaternion_round_trip_and_sign(rng: np.random.Generator) -> None:
    for _ in range(50):
        pose = g.random_pose(rng)
        t, q = g.pose_to_quat(pose)
        assert q[3] >= 0.0
        assert np.isclose(np.linalg.norm(q), 1.0)
        # float64 matrix → quaternion → matrix: a few ulp (~1e-15 measured), bound 1e-12
        np.testing.assert_allclose(g.pose_from_quat(t, q), pose, atol=1e-12)


def test_quaternion_convention_is_xyzw() -> None:
    # 90° about z: (x, y, z, w) = (0, 0, sin 45°, cos 45°) maps x to y.
    r = g.quat_to_matrix([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)  # sqrt(0.5) rounding: ~2e-16


def test_invert_and_relative(rng: np.random.Generator) -> None:
    a, b = g.random_pose(rng, 3.0), g.random_pose(rng, 3.0)
    # float64 round-off of two or three 4×4 products with translations of a few metres: ~1e-15, bound 1e-12
    np.testing.assert_allclose(g.invert(a) @ a, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(a @ g.relative(a, b), b, atol=1e-12)
    stack = np.stack([[a, b], [b, a], [g.random_pose(rng), np.eye(4)]])  # 3×2 poses: each inverted as one is
    inverses = g.invert(stack)
    assert inverses.shape == stack.shape
    for i, j in np.ndindex(3, 2):
        np.testing.assert_allclose(inverses[i, j], g.invert(stack[i, j]), atol=1e-15)


def test_transform_points_matches_homogeneous(rng: np.random.Generator) -> None:
    pose = g.random_pose(rng)
    pts = rng.normal(size=(20, 3))
    homog = (pose @ np.c_[pts, np.ones(20)].T).T[:, :3]
    np.testing.assert_allclose(g.transform_points(pose, pts), homog, atol=1e-12)  # one product each: ~1e-15


def test_planar_pose_and_yaw() -> None:
    pose = g.pose_from_planar(1.0, -2.0, 2.5)
    assert g.yaw_of(pose) == pytest.approx(2.5)
    assert pose[2, 3] == 0.0
    assert g.normalize_angle(3 * np.pi) == pytest.approx(np.pi)
    assert g.normalize_angle(-0.5) == pytest.approx(-0.5)


def test_so3_exp_log_and_angle(rng: np.random.Generator) -> None:
    v = rng.normal(size=3)
    v *= 1.2 / np.linalg.norm(v)
    np.testing.assert_allclose(g.so3_log(g.so3_exp(v)), v, atol=1e-12)  # 1.2 rad is far from π: ~1e-16
    assert g.rotation_angle(g.so3_exp(v)) == pytest.approx(1.2)
    np.testing.assert_allclose(g.skew(v) @ [1.0, 2.0, 3.0], np.cross(v, [1.0, 2.0, 3.0]))


def test_optical_frame_axes() -> None:
    # The camera's z (forward) is the body's x; its x (right) is the body's -y; its y (down) is -z.
    r = g.T_BODY_OPTICAL[:3, :3]
    np.testing.assert_allclose(r @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_allclose(r @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, -1])


def test_planar_camera_pose_keeps_the_base_on_the_floor() -> None:
    base_camera = g.make_pose(g.so3_exp([0.0, 0.1, 0.0]) @ g.T_BODY_OPTICAL[:3, :3], [0.1, 0.0, 0.5])
    planar = g.invert(base_camera) @ g.pose_from_planar(1.0, -0.5, 0.7) @ base_camera
    # An exactly planar camera motion is kept as it is.
    np.testing.assert_allclose(g.planar_camera_pose(planar, base_camera), planar, atol=1e-12)
    # Height, roll and pitch errors of the base are removed; x, y and yaw stay.
    lifted = g.invert(base_camera) @ g.pose_from_xyz_rpy(1.0, -0.5, 0.03, 0.01, -0.02, 0.7) @ base_camera
    projected = g.planar_camera_pose(lifted, base_camera)
    base = base_camera @ projected @ g.invert(base_camera)
    # Rz·Ry·Rx keeps the yaw in atan2(r10, r00) exactly: only the round-off of the products is left (~1e-15).
    assert abs(base[2, 3]) < 1e-12 and abs(base[2, 2] - 1.0) < 1e-12
    assert abs(g.yaw_of(base) - 0.7) < 1e-12 and np.allclose(base[:2, 3], [1.0, -0.5], rtol=0.0, atol=1e-12)
