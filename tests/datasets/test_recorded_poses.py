"""Camera poses from a recording's odometry and tf_static: the mounting chain and interpolation at frame stamps."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np

from fleetslam.datasets.recorded_poses import mounting, static_transforms
from fleetslam.geometry import make_pose, pose_to_quat, so3_exp
from fleetslam.trajectory import InterpolatedPose, Trajectory


def _tf(parent: str, child: str, pose: np.ndarray) -> NS:
    t, q = pose_to_quat(pose)
    return NS(
        header=NS(frame_id=parent),
        child_frame_id=child,
        transform=NS(translation=NS(x=t[0], y=t[1], z=t[2]), rotation=NS(x=q[0], y=q[1], z=q[2], w=q[3])),
    )


def test_mounting_composes_the_chain_from_the_camera_up_to_the_base() -> None:
    base_link = make_pose(so3_exp([0.0, 0.0, 0.3]), [0.1, 0.0, 0.4])
    link_optical = make_pose(so3_exp([-np.pi / 2, 0.0, -np.pi / 2]), [0.0, 0.02, 0.0])
    other = make_pose(translation=[5.0, 5.0, 5.0])
    messages = [
        NS(transforms=[_tf("base_link", "camera_link", other)]),  # replaced by the later message
        NS(transforms=[_tf("/base_link", "camera_link", base_link), _tf("camera_link", "optical", link_optical)]),
    ]
    transforms = static_transforms(messages)
    # float64 quaternion round trip of each link, then one product: ~1e-15 (3e-16 measured)
    np.testing.assert_allclose(mounting(transforms, "base_link", "optical"), base_link @ link_optical, atol=1e-12)
    np.testing.assert_allclose(mounting(transforms, "base_link", "base_link"), np.eye(4))
    assert mounting(transforms, "base_footprint", "optical") is None  # the chain ends at base_link
    looped = static_transforms([NS(transforms=[_tf("a", "b", other), _tf("b", "a", other)])])
    assert mounting(looped, "base_link", "a") is None


def test_interpolated_pose_between_samples_and_at_holes_and_ends() -> None:
    poses = [make_pose(so3_exp([0.0, 0.0, 0.2 * i]), [float(i), 0.0, 0.0]) for i in range(3)]
    lookup = InterpolatedPose(Trajectory.from_lists([1.0, 1.1, 2.0], poses), max_gap=0.25, tolerance=0.02)
    middle = lookup(1.025)
    assert middle is not None
    # slerp about one axis and a linear translation are exact up to round-off (1e-15 measured)
    np.testing.assert_allclose(middle, make_pose(so3_exp([0.0, 0.0, 0.05]), [0.25, 0.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(lookup(1.1), poses[1], atol=1e-12)
    assert lookup(1.5) is None  # 1.1 .. 2.0 is a hole
    np.testing.assert_allclose(lookup(0.99), poses[0])  # before the first pose, within the tolerance
    assert lookup(0.97) is None and lookup(2.03) is None
