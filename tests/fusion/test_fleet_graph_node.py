"""The fleet back-end node over a real router: two agents' graph updates in, placements and paths out."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.fusion.fleet_graph_node import FleetGraphConfig, FleetGraphNode, closure_covariance
from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphUpdate, graph_message
from fleetslam.geometry import invert, pose_from_planar
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import pose_matrix, pose_msg, transform_matrix
from fleetslam.msg.typesys import get_type, ns_from_stamp

from ..support import wait_until

R2D2_MAP = pose_from_planar(5.0, -3.0, 0.7)
"""r2d2's map frame in the fleet frame (c3po's map frame)."""


def _truth(agent: str) -> dict[int, np.ndarray]:
    offset = 0.0 if agent == "c3po" else 0.3
    return {i: pose_from_planar(0.5 * i, offset, 0.0) for i in range(20)}


def _inter_agent(frm: str, i: int, to: str, j: int, relative: np.ndarray, to_epoch: int) -> Any:
    return get_type("fleetslam_msgs/msg/GraphConstraint")(
        from_id=i, to_id=j, from_agent=frm, to_agent=to, kind=2, relative=pose_msg(relative),
        information=np.eye(6).reshape(36) * 1e4, to_epoch=to_epoch,
    )  # fmt: skip


class _Agent:
    """What an agent's SLAM node offers the back-end: ``graph_updates`` (deltas) and ``graph/full``."""

    def __init__(self, context: Context, own: dict[int, np.ndarray]) -> None:
        self.node = Node("slam", context=context)
        self.name = self.node.namespace.strip("/")
        self.own = own
        self.writer: GraphDeltaWriter[Any] = GraphDeltaWriter()
        self.constraints: list[Any] = []
        self.known: dict[int, np.ndarray] = {}
        updates = topics.GRAPH_UPDATES
        self.pub = self.node.create_publisher(updates.type, updates.name, updates.qos())
        self.node.create_service("fleetslam_msgs/srv/GetGraph", "graph/full", self.on_full)
        self.full_requests = 0

    def publish(self, ids: range, constraints: list[Any] = ()) -> None:  # type: ignore[assignment]
        self.known.update({i: self.own[i] for i in ids})
        self.constraints += constraints
        update = self.writer.update(self.known, {i: float(i) for i in self.known}, self.constraints)
        assert update is not None
        self.pub.publish(graph_message(self.name, update))

    def on_full(self, request: Any) -> Any:
        self.full_requests += 1
        full: GraphUpdate[Any] = self.writer.full(self.known, {i: float(i) for i in self.known}, self.constraints)
        return get_type("fleetslam_msgs/srv/GetGraph_Response")(graph=graph_message(self.name, full))


def test_the_back_end_places_two_agents_from_their_graph_updates(make_context: Callable[..., Context]) -> None:
    c3po_truth, r2d2_truth = _truth("c3po"), _truth("r2d2")
    c3po = _Agent(make_context("c3po"), c3po_truth)
    r2d2 = _Agent(make_context("r2d2"), {i: invert(R2D2_MAP) @ p for i, p in r2d2_truth.items()})
    c3po.publish(range(10))  # before the back-end runs: it will miss these and ask for the whole graph
    r2d2.publish(range(10))
    backend_node = Node("fleet_backend", context=make_context())
    backend = FleetGraphNode(backend_node, FleetGraphConfig(rate=10.0))
    viewer = Node("viewer", context=make_context())
    placements: list[Any] = []
    paths: list[Any] = []
    viewer.create_subscription(topics.FLEET_PLACEMENTS.type, topics.FLEET_PLACEMENTS.name, placements.append,
                               topics.FLEET_PLACEMENTS.qos(depth=5))  # fmt: skip
    viewer.create_subscription(topics.FLEET_PATH.type, topics.FLEET_PATH.of("r2d2"), paths.append,
                               topics.FLEET_PATH.qos(depth=5))  # fmt: skip
    diagnostics: list[Any] = []
    viewer.create_subscription(topics.FLEET_BACKEND_DIAGNOSTICS.type, topics.FLEET_BACKEND_DIAGNOSTICS.name,
                               diagnostics.append, topics.FLEET_BACKEND_DIAGNOSTICS.qos(depth=20))  # fmt: skip
    assert wait_until(lambda: backend._subscribed == {"c3po", "r2d2"}, 10.0)  # found in the graph
    # r2d2 recognises c3po at four places (exact closures), a delta the back-end receives after a gap.
    closures = [_inter_agent("r2d2", j, "c3po", j, invert(r2d2_truth[j]) @ c3po_truth[j], c3po.writer.epoch)
                for j in (0, 3, 6, 9)]  # fmt: skip
    r2d2.publish(range(10, 20), closures)
    c3po.publish(range(10, 20))

    def placed(agent: str) -> np.ndarray | None:
        for message in reversed(placements):
            for t in message.transforms:
                if t.child_frame_id == f"{agent}/map" and t.header.frame_id == "fleet":
                    return transform_matrix(t.transform)
        return None

    assert wait_until(lambda: placed("r2d2") is not None and backend.graph.agents["r2d2"].mirror.synced, 20.0)
    assert c3po.full_requests >= 1 and r2d2.full_requests >= 1  # the gap was filled from graph/full
    assert wait_until(lambda: len(backend.graph.agents["r2d2"].mirror.poses) == 20 and backend.solution is not None
                      and len(backend.solution.placements.get("r2d2", ()).poses or ()) == 20, 10.0)  # fmt: skip
    np.testing.assert_allclose(placed("c3po"), np.eye(4), atol=1e-3)  # the reference: the fleet frame
    r2d2_placed = placed("r2d2")
    assert r2d2_placed is not None
    np.testing.assert_allclose(r2d2_placed, R2D2_MAP, atol=1e-3)
    # The corrected path, in the fleet frame, each pose stamped with its keyframe's stamp.
    assert wait_until(lambda: bool(paths) and len(paths[-1].poses) == 20, 10.0)
    path = paths[-1]
    assert path.header.frame_id == "fleet"
    assert [ns_from_stamp(p.header.stamp) for p in path.poses] == [i * 1_000_000_000 for i in range(20)]
    np.testing.assert_allclose(pose_matrix(path.poses[15].pose), r2d2_truth[15], atol=1e-3)

    # What the solve did, for operators and benchmarks.
    # The solve that placed r2d2 reports it; a report of an earlier solve may still be the newest received.
    def latest() -> dict[str, str]:
        return {kv.key: kv.value for kv in diagnostics[-1].status[0].values} if diagnostics else {}

    assert wait_until(lambda: latest().get("agents_placed") == "2", 10.0), latest()
    values = latest()
    assert values["closures_kept"] == "4" and values["closures_rejected"] == "0"


def test_the_fleet_map_prefers_the_back_end_placement(make_context: Callable[..., Context]) -> None:
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode
    from fleetslam.msg.conversions import transform_msg

    fleet = FleetMapNode(Node("fleet_map", context=make_context()),
                         FleetMapConfig(resolution=0.1, agents=["r2d2"], publish_rate=5.0))  # fmt: skip
    latched = QoSProfile(durability="transient_local", depth=1)
    agent = Node("slam", context=make_context("r2d2"))
    own = agent.create_publisher("geometry_msgs/msg/TransformStamped", "slam/fleet_transform", latched)
    backend = Node("fleet_backend", context=make_context())
    placements = backend.create_publisher(topics.FLEET_PLACEMENTS.type, topics.FLEET_PLACEMENTS.name,
                                          topics.FLEET_PLACEMENTS.qos())  # fmt: skip
    by_slam, by_backend = pose_from_planar(10.0, 0.0, np.pi), pose_from_planar(10.3, 0.2, np.pi - 0.05)
    own.publish(transform_msg(by_slam, "fleet", "r2d2/map", 0).transforms[0])
    assert wait_until(lambda: (fleet._apply_placements(), "r2d2" in fleet.placed)[1], 10.0)
    np.testing.assert_allclose(fleet.placed["r2d2"], by_slam)
    placements.publish(transform_msg(by_backend, "fleet", "r2d2/map", 0))
    assert wait_until(lambda: (fleet._apply_placements(), np.allclose(fleet.placed["r2d2"], by_backend))[1], 10.0)
    own.publish(transform_msg(pose_from_planar(11.0, 0.0, np.pi), "fleet", "r2d2/map", 0).transforms[0])
    assert wait_until(lambda: "r2d2" in fleet._own_placement and fleet._own_placement["r2d2"][0, 3] == 11.0, 10.0)
    fleet._apply_placements()
    np.testing.assert_allclose(fleet.placed["r2d2"], by_backend)  # the back-end's is preferred
    # The back-end no longer places r2d2 (it restarted): its SLAM's own placement counts again.
    placements.publish(get_type("tf2_msgs/msg/TFMessage")(transforms=[]))
    assert wait_until(lambda: (fleet._apply_placements(), fleet.placed["r2d2"][0, 3] == 11.0)[1], 10.0)


def test_a_path_is_sent_again_no_sooner_than_its_bytes_allow(make_context: Callable[..., Context]) -> None:
    import time

    from fleetslam.msg.typesys import serialize

    c3po = _Agent(make_context("c3po"), _truth("c3po"))
    budget = 300.0  # bytes per second: a path of 10 keyframes (~1 kB) may go out again after ~3 s
    backend = FleetGraphNode(Node("fleet_backend", context=make_context()),
                             FleetGraphConfig(rate=10.0, agents=["c3po"], path_bytes_per_s=budget))  # fmt: skip
    arrivals: list[tuple[float, Any]] = []
    viewer = Node("viewer", context=make_context())
    viewer.create_subscription(topics.FLEET_PATH.type, topics.FLEET_PATH.of("c3po"),
                               lambda msg: arrivals.append((time.monotonic(), msg)),
                               topics.FLEET_PATH.qos(depth=5))  # fmt: skip
    assert wait_until(lambda: bool(backend._path_pubs["c3po"].matched_subscriptions), 10.0)
    c3po.publish(range(10))
    assert wait_until(lambda: bool(arrivals), 20.0)
    first_at, first = arrivals[0]
    assert len(first.poses) == 10
    c3po.publish(range(10, 20))  # new keyframes: the path is due again, but only once its bytes allow
    assert wait_until(lambda: len(backend.solution.placements["c3po"].poses) == 20, 10.0)  # type: ignore[union-attr]
    assert wait_until(lambda: len(arrivals[-1][1].poses) == 20, 20.0)
    assert len(arrivals) == 2
    assert arrivals[1][0] - first_at >= 0.9 * len(serialize(first, "nav_msgs/msg/Path")) / budget


def test_a_closure_s_information_becomes_its_covariance_unless_the_agent_sent_none() -> None:
    covariance = np.diag([1e-4, 4e-4, 9e-4, 1e-5, 2e-5, 3e-5])
    np.testing.assert_allclose(closure_covariance(np.linalg.inv(covariance).reshape(36)), covariance)
    assert closure_covariance(np.zeros(36)) is None  # an agent that sends no covariance: closure_sigma applies
    assert closure_covariance(np.full(36, np.nan)) is None
    assert closure_covariance(-np.eye(6).reshape(36)) is None  # not a covariance
