"""SE(3)/SO(3) helpers shared by every part of fleetslam (one place, not five).

Conventions:
- Poses are 4×4 homogeneous matrices ``T_a_b`` (float64) mapping points in frame b to frame a.
- Quaternions are ``(x, y, z, w)``, Hamilton, unit norm, as in ROS messages and TUM trajectory files.
- Point arrays are ``(N, 3)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Matrix4 = NDArray[np.float64]
Vector = NDArray[np.float64]


def quat_to_matrix(quat_xyzw: ArrayLike) -> NDArray[np.float64]:
    """3×3 rotation matrix of a quaternion ``(x, y, z, w)`` (normalised first)."""
    return np.asarray(Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix())


def matrix_to_quat(rotation: ArrayLike) -> Vector:
    """Quaternion ``(x, y, z, w)`` with ``w >= 0`` of a 3×3 rotation matrix."""
    q = Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)).as_quat()
    return np.asarray(-q if q[3] < 0 else q, dtype=np.float64)


def make_pose(rotation: ArrayLike | None = None, translation: ArrayLike | None = None) -> Matrix4:
    """4×4 pose from a 3×3 rotation (identity if None) and a translation (zero if None)."""
    pose = np.eye(4)
    if rotation is not None:
        pose[:3, :3] = np.asarray(rotation, dtype=np.float64)
    if translation is not None:
        pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


def pose_from_quat(translation: ArrayLike, quat_xyzw: ArrayLike) -> Matrix4:
    """4×4 pose from a translation and a quaternion ``(x, y, z, w)``."""
    return make_pose(quat_to_matrix(quat_xyzw), translation)


def pose_to_quat(pose: ArrayLike) -> tuple[Vector, Vector]:
    """Split a 4×4 pose into ``(translation (3,), quaternion (x, y, z, w))``."""
    pose = np.asarray(pose, dtype=np.float64)
    return pose[:3, 3].copy(), matrix_to_quat(pose[:3, :3])


def pose_from_xyz_rpy(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> Matrix4:
    """4×4 pose from a position and fixed-axis roll/pitch/yaw (radians), R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    rotation = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()
    return make_pose(rotation, [x, y, z])


def pose_from_planar(x: float, y: float, yaw: float) -> Matrix4:
    """4×4 pose of a planar robot at ``(x, y)`` heading ``yaw``."""
    return pose_from_xyz_rpy(x, y, 0.0, 0.0, 0.0, yaw)


def yaw_of(pose: ArrayLike) -> float:
    """Heading (rotation about z) of a pose or rotation matrix."""
    m = np.asarray(pose, dtype=np.float64)
    return float(np.arctan2(m[1, 0], m[0, 0]))


def invert(pose: ArrayLike) -> Matrix4:
    """Inverse of a rigid 4×4 pose, or of each of a stack of them (…×4×4; uses the transpose, not a general
    inverse)."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.ndim == 2:
        inv = np.eye(4)
        rt = pose[:3, :3].T
        inv[:3, :3] = rt
        inv[:3, 3] = -rt @ pose[:3, 3]
        return inv
    rts = np.swapaxes(pose[..., :3, :3], -1, -2)
    stack = np.broadcast_to(np.eye(4), pose.shape).copy()
    stack[..., :3, :3] = rts
    stack[..., :3, 3] = -(rts @ pose[..., :3, 3, None])[..., 0]
    return stack


def orthonormalized(pose: ArrayLike) -> Matrix4:
    """The pose with its rotation replaced by the nearest rotation matrix (SVD): chains of products drift off
    SO(3) by round-off, and :func:`invert`'s transpose then amplifies the drift."""
    out = np.array(pose, dtype=np.float64, copy=True)
    u, _, vt = np.linalg.svd(out[:3, :3])
    out[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return out


def relative(pose_a: ArrayLike, pose_b: ArrayLike) -> Matrix4:
    """Pose of b in a's frame: ``inv(T_w_a) · T_w_b``."""
    return invert(pose_a) @ np.asarray(pose_b, dtype=np.float64)


def transform_points(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a 4×4 pose to ``(N, 3)`` points."""
    pose = np.asarray(pose, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return pts @ pose[:3, :3].T + pose[:3, 3]


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """Skew-symmetric matrix ``[v]×``."""
    x, y, z = np.asarray(v, dtype=np.float64)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of a rotation vector (axis·angle), by Rodrigues' formula (the optimisers call it once per
    iteration; SciPy's general path costs ten times more)."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.sqrt(w @ w))
    k = skew(w)
    if theta < 1e-8:  # second-order series: exact to round-off at this size
        return np.eye(3) + k + 0.5 * (k @ k)
    return np.eye(3) + (np.sin(theta) / theta) * k + ((1.0 - np.cos(theta)) / theta**2) * (k @ k)


def so3_log(rotation: ArrayLike) -> Vector:
    """Rotation vector (axis·angle) of a rotation matrix: closed form away from a half turn, SciPy near it (where
    the closed form loses the axis)."""
    r = np.asarray(rotation, dtype=np.float64)
    cos = min(max((r[0, 0] + r[1, 1] + r[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    vee = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if cos > 0.99999:  # θ < 0.26°: sin θ ≈ θ to 1e-11 relative
        return vee * (1.0 + float(vee @ vee) / 6.0)
    if cos > -0.99:
        theta = float(np.arccos(cos))
        return vee * (theta / np.sin(theta))
    return np.asarray(Rotation.from_matrix(r).as_rotvec())


def interpolate_pose(a: ArrayLike, b: ArrayLike, fraction: float) -> Matrix4:
    """The pose a fraction of the way from ``a`` to ``b``: linear in translation, geodesic in rotation."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    out = np.eye(4)
    delta = a[:3, :3].T @ b[:3, :3]
    out[:3, :3] = a[:3, :3] @ so3_exp(fraction * so3_log(delta))
    out[:3, 3] = (1.0 - fraction) * a[:3, 3] + fraction * b[:3, 3]
    return out


def rotation_angle(pose_or_rotation: ArrayLike) -> float:
    """Angle (radians, in [0, π]) of the rotation part of a pose or rotation matrix."""
    m = np.asarray(pose_or_rotation, dtype=np.float64)[:3, :3]
    return float(np.linalg.norm(so3_log(m)))


def translation_distance(pose_a: ArrayLike, pose_b: ArrayLike) -> float:
    """Euclidean distance between the positions of two poses."""
    a = np.asarray(pose_a, dtype=np.float64)
    b = np.asarray(pose_b, dtype=np.float64)
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3]))


def random_pose(rng: np.random.Generator, translation_scale: float = 1.0) -> Matrix4:
    """A random rigid pose (uniform rotation, Gaussian translation); for tests and synthetic data."""
    rotation = Rotation.random(random_state=rng).as_matrix()
    return make_pose(rotation, rng.normal(scale=translation_scale, size=3))


def normalize_angle(angle: float) -> float:
    """Wrap an angle to ``(-π, π]``."""
    wrapped = (angle + np.pi) % (2.0 * np.pi) - np.pi
    return float(np.pi if wrapped == -np.pi else wrapped)


# Optical frame (x right, y down, z forward) relative to a body frame (x forward, y left, z up).
T_BODY_OPTICAL: Matrix4 = make_pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]))


def planar_camera_pose(T_camera0_camera: ArrayLike, T_base_camera: ArrayLike) -> Matrix4:
    """The camera pose (relative to an earlier camera pose) closest to one a ground robot can reach: the base
    under the camera keeps its height, roll and pitch, only x, y and yaw change (RTAB-Map's Reg/Force3DoF)."""
    base_camera = np.asarray(T_base_camera, dtype=np.float64)
    base_motion = base_camera @ np.asarray(T_camera0_camera, dtype=np.float64) @ invert(base_camera)
    yaw = float(np.arctan2(base_motion[1, 0], base_motion[0, 0]))
    planar = pose_from_planar(float(base_motion[0, 3]), float(base_motion[1, 3]), yaw)
    return invert(base_camera) @ planar @ base_camera
