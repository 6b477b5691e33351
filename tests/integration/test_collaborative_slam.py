"""Two SLAM nodes over a real router, no start poses: each recognises the other's keyframes (sent as summaries),
the graphs travel as deltas, and the second agent places its map frame in the fleet frame (the first one's); when it
restarts mid-run (a new map frame), the first drops their closures and it is placed again."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.drivers.node import CameraNode
from fleetslam.fusion.collaboration import CollaborationConfig
from fleetslam.geometry import invert, pose_from_planar, rotation_angle
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import pose_matrix, transform_matrix
from fleetslam.msg.typesys import get_type, ns_from_stamp
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.node import SlamNode, SlamNodeConfig
from fleetslam.slam.pipeline import SlamPipeline

from ..drivers.test_node import BASE_CAMERA, FrameListCamera
from ..slam.textured_room import make_textures, render
from ..support import wait_until

INTRINSICS = Intrinsics(262.5, 262.5, 159.5, 119.5, 320, 240)


def world_from_map(
    truth: dict[str, list[np.ndarray]],
    frames: dict[str, list[RGBDFrame]],
    poses: dict[str, dict[int, np.ndarray]],
    agent: str,
) -> np.ndarray:
    """An agent's map frame in the world, from its first tracked pose (SLAM's map frame is where it started)."""
    stamp_index = {round(f.stamp * 1e9): f.index for f in frames[agent]}
    stamp = min(poses[agent])
    return truth[agent][stamp_index[stamp]] @ invert(poses[agent][stamp])


def assert_close(estimate: np.ndarray | None, expected: np.ndarray) -> None:
    assert estimate is not None
    error = invert(expected) @ estimate
    assert np.linalg.norm(error[:3, 3]) < 0.05, error[:3, 3]
    assert np.degrees(rotation_angle(error)) < 1.0


CORNER_HEADING = 0.55
"""Heading (rad) of the robots: their cameras look into the room's (+x, +y) corner, two walls (a peer's view of one
plane is not believed)."""


def drive(x0: float, x1: float, y: float, count: int) -> list[np.ndarray]:
    """Camera poses of a robot starting at (``x0``, ``y``) and driving ``x1 - x0`` metres along its heading
    (:data:`CORNER_HEADING`; backwards when negative), its camera looking into the far corner."""
    c, s = np.cos(CORNER_HEADING), np.sin(CORNER_HEADING)
    steps = [(x1 - x0) * k / (count - 1) for k in range(count)]
    return [pose_from_planar(x0 + d * c, y + d * s, CORNER_HEADING) @ BASE_CAMERA for d in steps]


def camera_heard(camera: CameraNode) -> bool:
    """Whether the SLAM node's image and camera_info subscriptions are known to the camera's session: a frame
    published before that reaches no one (Zenoh routes a sample only to the subscriptions it already knows of), and
    a lost first half would hold the cameras' pacing by the poses up."""
    return all(pub.matched_subscriptions for pub in (camera.rgb_pub, camera.depth_pub, camera.rgb_info_pub))


def test_two_agents_find_each_other_and_the_second_is_placed_again_after_a_restart(
    make_context: Callable[..., Context],
) -> None:
    textures = make_textures(np.random.default_rng(5))
    truth = {"c3po": drive(-1.6, 0.8, 0.0, 25), "r2d2": drive(0.9, -1.5, 0.25, 25)}
    frames = {
        agent: [RGBDFrame(k, 3000.0 + 0.2 * k, *render(pose, INTRINSICS, textures)) for k, pose in enumerate(poses)]
        for agent, poses in truth.items()
    }
    warm = SlamPipeline(SlamConfig(), intrinsics=INTRINSICS)  # compile the kernels before the nodes run
    for frame in frames["c3po"][:3]:
        warm.step(frame)

    config = {agent: SlamNodeConfig(peers=[peer]) for agent, peer in (("c3po", "r2d2"), ("r2d2", "c3po"))}
    slam = {agent: SlamNode(Node("slam", context=make_context(agent)), config[agent]) for agent in truth}
    poses: dict[str, dict[int, np.ndarray]] = {agent: {} for agent in truth}
    fleet_tf: list[Any] = []
    fleet_poses: list[Any] = []
    summary_bytes: list[int] = []
    with Node("listener", context=make_context()) as listener:
        for agent in truth:
            listener.create_subscription(
                "nav_msgs/msg/Odometry", f"/{agent}/slam/odom",
                lambda msg, a=agent: poses[a].__setitem__(ns_from_stamp(msg.header.stamp), pose_matrix(msg.pose.pose)),
            )  # fmt: skip
        listener.create_subscription("tf2_msgs/msg/TFMessage", "/r2d2/tf", fleet_tf.append, QoSProfile(depth=50))
        listener.create_subscription("geometry_msgs/msg/PoseStamped", "/r2d2/slam/fleet_pose", fleet_poses.append)
        listener.create_subscription(
            "fleetslam_msgs/msg/KeyframeSummary", "/c3po/keyframe_summaries",
            lambda data: summary_bytes.append(len(data)), QoSProfile(depth=50), raw=True,
        )  # fmt: skip
        cameras = {}
        for agent in truth:
            driver = FrameListCamera(
                INTRINSICS, frames[agent], rate=5.0, ready=lambda i, a=agent: len(poses[a]) >= i - 1
            )
            node = Node("camera", context=make_context(), namespace=f"/{agent}")
            cameras[agent] = (CameraNode(node, driver, base_camera=BASE_CAMERA), driver)
        assert wait_until(lambda: all(s.base_camera is not None for s in slam.values()), 10.0)
        assert wait_until(lambda: all(camera_heard(camera) for camera, _ in cameras.values()), 10.0)
        for camera, driver in cameras.values():
            camera.start()
            driver.go.set()
        for camera, _ in cameras.values():  # on failure: frames processed, received, dropped, pending per agent
            assert camera.join(60.0), {a: (n.frames, n.queue.received, n.queue.dropped, n.queue.pending)
                                       for a, n in slam.items()}  # fmt: skip
        assert wait_until(lambda: slam["r2d2"].fleet_transform is not None, 20.0), (
            slam["r2d2"].counts, {p: s.decision for p, s in slam["r2d2"].linker.peers.items()},
        )  # fmt: skip
        assert wait_until(lambda: fleet_poses and any(
            t.header.frame_id == "fleet" and t.child_frame_id == "r2d2/map" for m in fleet_tf for t in m.transforms
        ), 10.0)  # fmt: skip
        for camera, _ in cameras.values():
            camera.close()
        first_run = {agent: dict(agent_poses) for agent, agent_poses in poses.items()}
        (published,) = [t for m in fleet_tf for t in m.transforms if t.child_frame_id == "r2d2/map"][-1:]
        expected = invert(world_from_map(truth, frames, first_run, "c3po")) @ world_from_map(
            truth, frames, first_run, "r2d2"
        )
        for estimate in (slam["r2d2"].fleet_transform, transform_matrix(published.transform)):
            assert_close(estimate, expected)

        # r2d2 restarts (a new map frame, a new graph epoch): c3po drops its closures with r2d2, and r2d2 is placed
        # again by new ones as both drive on.
        keyframes_before = slam["r2d2"].counts["keyframes"]
        reset = listener.create_client("std_srvs/srv/Trigger", "/r2d2/slam/reset")
        assert reset.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=10.0).success
        assert slam["r2d2"].fleet_transform is None
        again = {agent: [RGBDFrame(f.index, f.stamp + 100.0, f.rgb, f.depth) for f in frames[agent]] for agent in truth}
        for agent in truth:
            poses[agent].clear()
            driver = FrameListCamera(
                INTRINSICS, again[agent], rate=5.0, ready=lambda i, a=agent: len(poses[a]) >= i - 1
            )
            cameras[agent] = (CameraNode(Node("camera2", context=make_context(), namespace=f"/{agent}"), driver,
                                         base_camera=BASE_CAMERA), driver)  # fmt: skip
            assert wait_until(partial(camera_heard, cameras[agent][0]), 10.0)
            cameras[agent][0].start()
            driver.go.set()
        for camera, _ in cameras.values():  # on failure: frames processed, received, dropped, pending per agent
            assert camera.join(60.0), {a: (n.frames, n.queue.received, n.queue.dropped, n.queue.pending)
                                       for a, n in slam.items()}  # fmt: skip
        assert wait_until(lambda: slam["r2d2"].fleet_transform is not None, 20.0), slam["r2d2"].counts
        assert slam["c3po"].linker.peers["r2d2"].restarts == 1
        for camera, _ in cameras.values():
            camera.close()
        expected = invert(world_from_map(truth, frames, first_run, "c3po")) @ world_from_map(
            truth, again, poses, "r2d2"
        )
        assert_close(slam["r2d2"].fleet_transform, expected)
    assert fleet_poses[-1].header.frame_id == "fleet"
    # Summaries, not images, on the wire; the peers' graphs mirrored from deltas.
    assert summary_bytes and max(summary_bytes) <= 20_000
    mirror = slam["c3po"].linker.peers["r2d2"].mirror
    writer = slam["r2d2"].graph_writer
    assert mirror.synced and mirror.sequence == writer.sequence and len(mirror.poses) == writer.sent_keyframes
    keyframes = slam["r2d2"].counts["keyframes"] - keyframes_before  # since the restart
    assert writer.sent_keyframes >= keyframes - 1  # the newest may wait for graph_period
    assert slam["c3po"].counts["bad_peer_messages"] == slam["r2d2"].counts["bad_peer_messages"] == 0
    # Each placement rests on at least three closures of the pair, verified by either agent (each shares its own):
    # three before the restart, three after, at least; r2d2 verified some itself.
    verified = {agent: node.counts["peer_closures"] for agent, node in slam.items()}
    assert sum(verified.values()) >= 6 and verified["r2d2"] >= 1, verified


def test_a_late_agent_is_placed_from_the_closures_the_other_shares(make_context: Callable[..., Context]) -> None:
    """c3po maps first and stands still; r2d2 starts afterwards. r2d2 never receives c3po's keyframes (they were sent
    before it joined, and its catch-up on missed summaries is off here), so it is placed from the closures c3po
    verifies against r2d2's keyframes and shares in its graph (r2d2 fetches the graph it missed the start of)."""
    textures = make_textures(np.random.default_rng(5))
    truth = {"c3po": drive(-1.6, 0.8, 0.0, 25), "r2d2": drive(0.9, -1.5, 0.25, 25)}
    frames = {
        agent: [RGBDFrame(k, 3000.0 + 0.2 * k, *render(pose, INTRINSICS, textures)) for k, pose in enumerate(poses)]
        for agent, poses in truth.items()
    }
    warm = SlamPipeline(SlamConfig(), intrinsics=INTRINSICS)
    for frame in frames["c3po"][:3]:
        warm.step(frame)
    poses: dict[str, dict[int, np.ndarray]] = {agent: {} for agent in truth}
    slam: dict[str, SlamNode] = {}
    with Node("listener", context=make_context()) as listener:
        for agent in truth:
            listener.create_subscription(
                "nav_msgs/msg/Odometry", f"/{agent}/slam/odom",
                lambda msg, a=agent: poses[a].__setitem__(ns_from_stamp(msg.header.stamp), pose_matrix(msg.pose.pose)),
            )  # fmt: skip
        for agent in ("c3po", "r2d2"):
            peer = "r2d2" if agent == "c3po" else "c3po"
            config = SlamNodeConfig(peers=[peer], collaboration=CollaborationConfig(catch_up=False))
            slam[agent] = SlamNode(Node("slam", context=make_context(agent)), config)
            driver = FrameListCamera(
                INTRINSICS, frames[agent], rate=5.0, ready=lambda i, a=agent: len(poses[a]) >= i - 1
            )
            camera = CameraNode(Node("camera", context=make_context(), namespace=f"/{agent}"), driver,
                                base_camera=BASE_CAMERA)  # fmt: skip
            assert wait_until(lambda a=agent: slam[a].base_camera is not None, 10.0)
            assert wait_until(partial(camera_heard, camera), 10.0)
            camera.start()
            driver.go.set()
            assert camera.join(60.0), (slam[agent].frames, slam[agent].queue.received, slam[agent].queue.pending)
            assert wait_until(lambda a=agent: len(poses[a]) >= 24, 20.0)
            camera.close()
        assert wait_until(lambda: slam["r2d2"].fleet_transform is not None, 30.0), (
            slam["r2d2"].counts, slam["c3po"].counts, {p: s.decision for p, s in slam["r2d2"].linker.peers.items()},
        )  # fmt: skip
    assert slam["r2d2"].counts["peer_closures"] == 0  # nothing of c3po's to recognise: placed by what c3po shared
    assert slam["c3po"].counts["peer_closures"] >= 3
    assert slam["r2d2"].counts["graph_requests"] >= 1  # it joined c3po's graph updates late
    expected = invert(world_from_map(truth, frames, poses, "c3po")) @ world_from_map(truth, frames, poses, "r2d2")
    assert_close(slam["r2d2"].fleet_transform, expected)
