"""The mapping node over a real router: keyframes in, occupancy products and services out."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from fleetslam.geometry import T_BODY_OPTICAL, pose_from_planar, pose_to_quat
from fleetslam.mapping.node import MappingNode, MappingNodeConfig, PublishPacer
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import get_type, message_from_dict

from ..support import wait_until


def _keyframe(keyframe_id: int, pose: np.ndarray, distance: float) -> Any:
    depth_mm = np.full((48, 64), int(distance * 1000), np.uint16)
    ok, png = cv2.imencode(".png", depth_mm)
    assert ok
    t, q = pose_to_quat(pose)
    msg = message_from_dict(
        "fleetslam_msgs/msg/Keyframe",
        {"agent": "c3po", "id": keyframe_id, "depth_format": "png16_mm", "depth": png.reshape(-1).tolist(),
         "camera_info": {"width": 64, "height": 48, "k": [50.0, 0, 32.0, 0, 50.0, 24.0, 0, 0, 1]},
         "pose": {"position": dict(zip("xyz", t.tolist(), strict=True)),
                  "orientation": dict(zip("xyzw", q.tolist(), strict=True))}},
    )  # fmt: skip
    return msg


def test_mapping_node_maps_keyframes_and_serves(make_context: Callable[..., Context], tmp_path: Path) -> None:
    mapping = Node("mapping", context=make_context("c3po"))
    MappingNode(mapping, MappingNodeConfig(publish_rate=5.0, pixel_stride=2, maps_dir=str(tmp_path)))
    slam = Node("slam", context=make_context("c3po"))
    clouds: list[Any] = []
    octomaps: list[Any] = []
    grids: list[Any] = []
    viewer = Node("viewer", context=make_context())
    viewer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied", clouds.append, QoSProfile(depth=5))
    viewer.create_subscription("octomap_msgs/msg/Octomap", "/c3po/map/octomap", octomaps.append, QoSProfile(depth=5))
    viewer.create_subscription("nav_msgs/msg/OccupancyGrid", "/c3po/map/grid", grids.append, QoSProfile(depth=5))
    keyframes = slam.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    assert wait_until(lambda: keyframes.matched_subscriptions > 0, 10.0)  # a keyframe sent before is lost
    keyframes.publish(_keyframe(0, camera, 2.0))
    assert wait_until(lambda: bool(clouds) and bool(octomaps) and bool(grids), 10.0)
    cloud = clouds[-1]
    xyz = np.frombuffer(bytes(cloud.data), np.float32).reshape(-1, 3)
    # The wall, 2 m ahead: centres of the layer [2.0, 2.05); the layers beside it are 0.05 off.
    assert len(xyz) > 100 and np.allclose(xyz[:, 0], 2.0 + 0.025, atol=0.03)
    assert octomaps[-1].id == "OcTree" and octomaps[-1].binary and len(octomaps[-1].data) > 0
    assert grids[-1].info.width > 0 and 100 in set(np.asarray(grids[-1].data).tolist())
    save = viewer.create_client("fleetslam_msgs/srv/SaveMap", "/c3po/map/save")
    assert save.wait_for_service(5.0)
    response = save.call(get_type("fleetslam_msgs/srv/SaveMap_Request")(path="c3po.bt"), timeout=10)
    assert response.success, response.message
    octomap = pytest.importorskip("octomap", reason="octomap-python is the oracle")
    in_file = octomap.OcTree(str(tmp_path / "c3po.bt").encode())
    assert response.message.startswith(f"{in_file.size()} nodes written"), response.message
    saved = OccupancyOctree.read(tmp_path / "c3po.bt")
    assert saved.is_occupied([2.025, 0.025, 0.525])
    reset = viewer.create_client("std_srvs/srv/Trigger", "/c3po/map/reset")
    assert reset.wait_for_service(5.0)
    assert reset.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=10).success
    assert wait_until(lambda: clouds[-1].width == 0, 5.0)


def _graph(poses: dict[int, np.ndarray], sequence: int, *, full: bool = False) -> Any:
    """A graph update as SLAM publishes it on ``graph_updates`` (or answers on ``graph/full``)."""
    entries = []
    for pose in poses.values():
        t, q = pose_to_quat(pose)
        entries.append({"position": dict(zip("xyz", t.tolist(), strict=True)),
                        "orientation": dict(zip("xyzw", q.tolist(), strict=True))})  # fmt: skip
    return message_from_dict(
        "fleetslam_msgs/msg/KeyframeGraph",
        {"agent": "c3po", "keyframe_ids": list(poses), "poses": entries, "sequence": sequence, "full": full,
         "epoch": 7, "stamps": [{"sec": i, "nanosec": 0} for i in poses]},
    )  # fmt: skip


def test_mapping_node_follows_the_latest_graph_and_builds_only_what_is_subscribed(
    make_context: Callable[..., Context],
) -> None:
    config = MappingNodeConfig(publish_rate=5.0, reintegrate_period=0.5)
    mapping = MappingNode(Node("mapping", context=make_context("c3po")), config)
    slam = Node("slam", context=make_context("c3po"))
    viewer = Node("viewer", context=make_context())
    clouds: list[Any] = []
    markers: list[Any] = []
    viewer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied", clouds.append, QoSProfile(depth=5))
    keyframes = slam.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
    graph = slam.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph_updates", QoSProfile(depth=50))
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    assert wait_until(lambda: keyframes.matched_subscriptions > 0 and graph.matched_subscriptions > 0, 10.0)
    keyframes.publish(_keyframe(0, camera, 2.0))  # a wall 2 m ahead: x = 2
    keyframes.publish(_keyframe(1, camera, 2.0))

    def wall_at(x: float) -> bool:
        if not clouds:
            return False
        xyz = np.frombuffer(bytes(clouds[-1].data), np.float32).reshape(-1, 3)
        return len(xyz) > 100 and bool(np.allclose(xyz[:, 0], x + 0.025, atol=0.03))

    assert wait_until(lambda: wall_at(2.0), 10.0)
    # Graph updates in quick succession (optimisations moving both keyframes): applied in order, the last counts.
    for sequence, shift in enumerate((0.2, 0.35, 0.5), start=1):
        graph.publish(
            _graph({0: pose_from_planar(shift, 0.0, 0.0) @ camera, 1: pose_from_planar(shift, 0, 0) @ camera}, sequence)
        )
    assert wait_until(lambda: wall_at(2.5), 10.0)  # both keyframes moved: rebuilt where the graph put them
    assert mapping.mapper.pending == 0
    # Nobody subscribed to the markers or the grid: never built. A viewer that comes gets the current map.
    assert mapping._published["markers"] == 0 and mapping._published["grid"] == 0
    viewer.create_subscription("visualization_msgs/msg/MarkerArray", "/c3po/map/markers", markers.append,
                               QoSProfile(durability="transient_local", depth=1))  # fmt: skip
    assert wait_until(lambda: bool(markers), 10.0)
    cubes = np.array([(p.x, p.y, p.z) for marker in markers[-1].markers for p in marker.points])
    assert len(cubes) > 100 and np.allclose(cubes[:, 0], 2.525, atol=0.03)


def test_publications_are_spaced_by_their_cost() -> None:
    now = [100.0]
    pacer = PublishPacer(0.05, clock=lambda: now[0])

    def build(seconds: float, did: bool = True) -> Callable[[], bool]:
        def work() -> bool:
            now[0] += seconds
            return did

        return work

    assert pacer.due()
    assert pacer.timed(build(0.2))  # 0.2 s of work at 5 %: the next one 4 s after it began
    now[0] = 103.9
    assert not pacer.due()
    now[0] = 104.001
    assert pacer.due()
    assert not pacer.timed(build(0.5, did=False))  # nothing published: no wait
    assert pacer.due()


def test_save_requests_naming_anything_but_a_file_in_the_maps_directory_are_refused(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    maps, outside = tmp_path / "maps", tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.bt").write_text("keep me")
    (maps / "sub").mkdir(parents=True)
    (maps / "link.bt").symlink_to(outside / "victim.bt")
    MappingNode(Node("mapping", context=make_context("c3po")), MappingNodeConfig(maps_dir=str(maps)))
    viewer = Node("viewer", context=make_context())
    save = viewer.create_client("fleetslam_msgs/srv/SaveMap", "/c3po/map/save")
    assert save.wait_for_service(5.0)
    request = get_type("fleetslam_msgs/srv/SaveMap_Request")
    attacks = {
        str(outside / "victim.bt"): "not a plain file name",
        "../outside/victim.bt": "not a plain file name",
        "..": "not a plain file name",
        "sub/x.bt": "not a plain file name",
        ".hidden.bt": "not a plain file name",
        "map.yaml": "must end in .bt or .ot",
        "link.bt": "is a link",
    }
    for path, reason in attacks.items():
        response = save.call(request(path=path), timeout=10)
        assert not response.success and reason in response.message, (path, response.message)
    assert (outside / "victim.bt").read_text() == "keep me"
    assert sorted(p.name for p in maps.iterdir()) == ["link.bt", "sub"] and not any((maps / "sub").iterdir())
    response = save.call(request(path=""), timeout=10)  # the default name, inside the maps directory
    assert response.success and Path(response.path) == maps / "map.bt", response.message


def test_a_keyframe_or_graph_with_a_nan_pose_or_no_focal_length_is_left_out_and_the_map_goes_on(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    mapping = MappingNode(Node("mapping", context=make_context("c3po")),
                          MappingNodeConfig(publish_rate=5.0, maps_dir=str(tmp_path)))  # fmt: skip
    slam = Node("slam", context=make_context("c3po"))
    viewer = Node("viewer", context=make_context())
    clouds: list[Any] = []
    viewer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied", clouds.append, QoSProfile(depth=5))
    keyframes = slam.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
    graph = slam.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph_updates", QoSProfile(depth=50))
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    assert wait_until(lambda: keyframes.matched_subscriptions > 0 and graph.matched_subscriptions > 0, 10.0)
    poisoned = _keyframe(0, camera, 2.0)
    poisoned.pose.position.x = float("nan")
    keyframes.publish(poisoned)
    zero_rotation = _keyframe(1, camera, 2.0)
    zero_rotation.pose.orientation.x = zero_rotation.pose.orientation.y = 0.0
    zero_rotation.pose.orientation.z = zero_rotation.pose.orientation.w = 0.0
    keyframes.publish(zero_rotation)
    no_focal_length = _keyframe(4, camera, 2.0)
    no_focal_length.camera_info.k[0] = 0.0  # every point would be infinite
    keyframes.publish(no_focal_length)
    assert wait_until(lambda: mapping.rejected == 3, 10.0), mapping.rejected
    assert 4 not in mapping.mapper.scans
    keyframes.publish(_keyframe(2, camera, 2.0))
    assert wait_until(lambda: bool(clouds) and clouds[-1].width > 100, 10.0)  # the map still grows
    bad_graph = _graph({2: camera}, 1)
    bad_graph.poses[0].position.z = float("inf")
    graph.publish(bad_graph)
    assert wait_until(lambda: mapping.rejected == 4, 10.0), mapping.rejected
    np.testing.assert_allclose(mapping.mapper.scans[2].pose, camera)  # the bad graph changed nothing
    keyframes.publish(_keyframe(3, pose_from_planar(0.5, 0.0, 0.0) @ camera, 2.0))  # and later keyframes count
    assert wait_until(lambda: mapping.mapper.pending == 0 and 3 in mapping.mapper.scans, 10.0)
    save = viewer.create_client("fleetslam_msgs/srv/SaveMap", "/c3po/map/save")
    assert save.wait_for_service(5.0)
    response = save.call(get_type("fleetslam_msgs/srv/SaveMap_Request")(path="after.bt"), timeout=10)
    assert response.success, response.message
    assert OccupancyOctree.read(tmp_path / "after.bt").is_occupied([2.525, 0.025, 0.525])


def test_a_mapping_node_that_missed_the_start_of_the_graph_fetches_it_whole(
    make_context: Callable[..., Context],
) -> None:
    """Started after SLAM: the first update it hears is number 6. It asks SLAM's ``graph/full`` (a real service over
    the router, answering as SLAM does: the whole graph as of update 5), then applies 6 after it."""
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    slam = Node("slam", context=make_context("c3po"))
    requests: list[Any] = []

    def whole_graph(request: Any) -> Any:
        requests.append(request)
        whole = _graph({0: pose_from_planar(0.3, 0.0, 0.0) @ camera, 1: camera}, 5, full=True)
        return get_type("fleetslam_msgs/srv/GetGraph_Response")(graph=whole)

    slam.create_service("fleetslam_msgs/srv/GetGraph", "graph/full", whole_graph)
    mapping = MappingNode(Node("mapping", context=make_context("c3po")), MappingNodeConfig(publish_rate=5.0))
    keyframes = slam.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
    graph = slam.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph_updates", QoSProfile(depth=50))
    assert wait_until(lambda: keyframes.matched_subscriptions > 0 and graph.matched_subscriptions > 0, 10.0)
    keyframes.publish(_keyframe(0, camera, 2.0))
    keyframes.publish(_keyframe(1, camera, 2.0))
    assert wait_until(lambda: 0 in mapping.mapper.scans and 1 in mapping.mapper.scans, 10.0)
    graph.publish(_graph({1: pose_from_planar(0.1, 0.0, 0.0) @ camera}, 6))  # update 6: only keyframe 1 moved
    assert wait_until(lambda: mapping.graph.synced and mapping.graph.sequence == 6, 10.0), mapping.graph
    assert len(requests) == 1
    assert wait_until(lambda: mapping.mapper.pending == 0, 10.0)
    np.testing.assert_allclose(mapping.mapper.scans[0].pose, pose_from_planar(0.3, 0.0, 0.0) @ camera, atol=1e-9)
    np.testing.assert_allclose(mapping.mapper.scans[1].pose, pose_from_planar(0.1, 0.0, 0.0) @ camera, atol=1e-9)
