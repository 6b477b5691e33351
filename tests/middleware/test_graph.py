import time
from collections.abc import Callable

import pytest

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.wire import EntityKind, LivelinessToken


def test_graph_tracks_entities_types_gids_and_their_removal(make_context: Callable[..., Context]) -> None:
    observer = make_context()
    graph = observer.graph
    events: list[tuple[str, EntityKind]] = []
    graph.add_listener(lambda event, token: events.append((event, token.kind)))
    ctx = make_context("c3po")
    node = Node("slam", context=ctx)
    pub = node.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph", QoSProfile(depth=3))
    sub = node.create_subscription(
        "nav_msgs/msg/Odometry", "odom", lambda m: None, QoSProfile(reliability="best_effort", depth=5)
    )
    node.create_service("std_srvs/srv/Trigger", "slam/reset", lambda r: r)
    client = node.create_client("std_srvs/srv/Trigger", "/c3po/e_stop")
    assert graph.wait_for(lambda g: len(g.node_entities("/c3po", "slam")) == 4, 5)
    (info,) = graph.nodes()[-1:]
    assert (info.fq_name, info.zid, info.nid) == ("/c3po/slam", ctx.zid, node.node_id)
    assert "/c3po/slam" in graph.node_fq_names() and ("/c3po", "slam") in graph.node_names()
    topics = graph.topic_names_and_types()
    assert topics["/c3po/graph"] == ["fleetslam_msgs/msg/KeyframeGraph"]
    assert topics["/c3po/odom"] == ["nav_msgs/msg/Odometry"]
    assert graph.service_names_and_types() == {
        "/c3po/e_stop": ["std_srvs/srv/Trigger"],
        "/c3po/slam/reset": ["std_srvs/srv/Trigger"],
    }
    (p,) = graph.publishers_info("/c3po/graph")
    assert (p.node_fq_name, p.qos.depth, p.gid, p.zid, p.kind) == (
        "/c3po/slam",
        3,
        pub.gid,
        ctx.zid,
        EntityKind.PUBLISHER,
    )
    assert p.type_hash.startswith("RIHS01_") and p.topic_type == "fleetslam_msgs/msg/KeyframeGraph"
    (s,) = graph.subscriptions_info("/c3po/odom")
    assert (s.gid, s.qos.reliability, s.qos.depth) == (sub.gid, "best_effort", 5)
    assert graph.clients_info("/c3po/e_stop")[0].gid == client.gid
    assert len(graph.services_info("/c3po/slam/reset")) == 1
    token = graph.entity_by_gid(pub.gid)
    assert isinstance(token, LivelinessToken) and token.node_fq_name == "/c3po/slam"
    assert ("put", EntityKind.NODE) in events and ("put", EntityKind.CLIENT) in events
    ctx.close()
    assert graph.wait_for(lambda g: "/c3po/slam" not in g.node_fq_names(), 5)
    assert graph.wait_for(lambda g: not g.publishers_info("/c3po/graph") and not g.services_info("/c3po/slam/reset"), 5)
    assert graph.entity_by_gid(pub.gid) is None
    assert ("delete", EntityKind.NODE) in events and ("delete", EntityKind.SUBSCRIBER) in events
    assert sorted(events) == sorted([(e, k) for e in ("put", "delete") for k in EntityKind])  # each change once


def test_graph_started_late_sees_existing_entities_and_other_domains_not(make_context: Callable[..., Context]) -> None:
    ctx = make_context("c3po")
    Node("base", context=ctx).create_publisher("nav_msgs/msg/Odometry", "odom")
    Node("elsewhere", context=make_context(domain_id=3))
    time.sleep(0.3)
    observer = make_context()
    # The initial liveliness query already answers: no waiting needed for entities that existed before.
    graph = observer.graph
    assert graph.wait_for(lambda g: bool(g.publishers_info("/c3po/odom")), 2.0)
    assert "/elsewhere" not in graph.node_fq_names()
    assert not graph.wait_for(lambda g: "/nobody" in g.node_fq_names(), 0.1)


def test_wait_for_sees_a_node_destroyed_alone(make_context: Callable[..., Context]) -> None:
    graph = make_context().graph
    ctx = make_context()
    keep = Node("keep", context=ctx)
    gone = Node("gone", context=ctx)
    assert graph.wait_for(lambda g: {"/keep", "/gone"} <= set(g.node_fq_names()), 5)
    gone.destroy()
    assert graph.wait_for(lambda g: "/gone" not in g.node_fq_names(), 5)
    assert "/keep" in graph.node_fq_names() and keep.context is ctx


def test_node_cli_prints_like_ros2(
    fleet_env: str, make_context: Callable[..., Context], capsys: pytest.CaptureFixture[str]
) -> None:
    from fleetslam.cli.main import main

    ctx = make_context("c3po")
    node = Node("base", context=ctx, statistics_period_s=0)
    node.create_subscription("geometry_msgs/msg/Twist", "cmd_vel", lambda m: None)
    node.create_publisher("nav_msgs/msg/Odometry", "odom")
    node.create_client("std_srvs/srv/Trigger", "/c3po/e_stop")
    Node("_hidden", context=ctx, statistics_period_s=0)
    assert ctx.graph.wait_for(lambda g: len(g.node_entities("/c3po", "base")) == 3, 5)
    assert main(["node", "list", "--wait", "0.2"]) == 0
    assert capsys.readouterr().out.split() == ["/c3po/base"]
    assert main(["node", "list", "-a", "-c", "--wait", "0.2"]) == 0
    assert capsys.readouterr().out.strip() == "3"  # base, _hidden and the command's own node
    assert main(["node", "info", "/c3po/base", "--wait", "0.2"]) == 0
    assert capsys.readouterr().out == (
        "/c3po/base\n"
        "  Subscribers:\n    /c3po/cmd_vel: geometry_msgs/msg/Twist\n"
        "  Publishers:\n    /c3po/odom: nav_msgs/msg/Odometry\n"
        "  Service Servers:\n"
        "  Service Clients:\n    /c3po/e_stop: std_srvs/srv/Trigger\n"
    )
    assert main(["node", "info", "/c3po/nobody", "--wait", "0.2"]) != 0
    assert "Unable to find node '/c3po/nobody'" in capsys.readouterr().err
