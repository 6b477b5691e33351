"""Whole-graph requests over a real router: one per agent at a time, off the caller's thread, failures survived."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from fleetslam.fusion.graph_exchange import GraphDeltaWriter, graph_message
from fleetslam.fusion.graph_fetcher import GraphFetcher
from fleetslam.geometry import pose_from_planar
from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import get_type

from ..support import wait_until


class _SlowAgent:
    """An agent's ``graph/full`` that answers only when the test lets it (or fails when told to)."""

    def __init__(self, context: Context) -> None:
        self.node = Node("slam", context=context)
        self.name = self.node.namespace.strip("/")
        self.release = threading.Event()
        self.fail = False
        self.requests = 0
        self.node.create_service("fleetslam_msgs/srv/GetGraph", "graph/full", self.on_full)

    def on_full(self, request: Any) -> Any:
        self.requests += 1
        self.release.wait(10.0)
        if self.fail:
            raise RuntimeError("graph unavailable")
        poses = {i: pose_from_planar(0.5 * i, 0.0, 0.0) for i in range(3)}
        stamps = {i: float(i) for i in poses}
        writer = GraphDeltaWriter[Any]()
        writer.update(poses, stamps, [])  # sent as a delta: the whole graph holds what was sent
        full = writer.full(poses, stamps, [])
        return get_type("fleetslam_msgs/srv/GetGraph_Response")(graph=graph_message(self.name, full))


def test_one_request_per_agent_at_a_time_and_the_next_after_a_failure(make_context: Callable[..., Context]) -> None:
    agent = _SlowAgent(make_context("c3po"))
    received: list[tuple[str, Any]] = []
    reader = Node("reader", context=make_context())
    fetcher = GraphFetcher(reader.create_client, lambda a, g: received.append((a, g)), name=reader.fq_name)
    assert not fetcher.request("c3po")  # never added: nothing to ask
    fetcher.add("c3po")
    assert wait_until(lambda: fetcher.request("c3po"), 10.0)
    assert wait_until(lambda: agent.requests == 1, 10.0)
    assert fetcher.in_flight("c3po") and not fetcher.request("c3po")  # a burst of gaps asks once
    agent.release.set()
    assert wait_until(lambda: len(received) == 1 and not fetcher.in_flight("c3po"), 10.0)
    name, graph = received[0]
    assert name == "c3po" and graph.agent == "c3po" and len(graph.keyframe_ids) == 3

    agent.fail = True  # the answer is an error: logged, and the next gap asks again
    assert fetcher.request("c3po")
    assert wait_until(lambda: agent.requests == 2 and not fetcher.in_flight("c3po"), 10.0)
    assert len(received) == 1
    agent.fail = False
    assert fetcher.request("c3po")
    assert wait_until(lambda: len(received) == 2, 10.0)
