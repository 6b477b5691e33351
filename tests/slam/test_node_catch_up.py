"""The SLAM node's summary catch-up over a real router: it asks a peer for the summaries of keyframes the peer's graph
names but whose summaries never came, survives hostile answers (and a peer too slow to answer), and answers
requests for its own summaries, hostile ones included, without stalling."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from fleetslam.datasets.base import Intrinsics
from fleetslam.fusion.collaboration import CollaborationConfig
from fleetslam.fusion.keyframe_summary import KeyframeSummary, summarize, summary_fields, summary_from_message
from fleetslam.fusion.summary_catchup import MAX_REQUEST_IDS, SummaryStore
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.wire import encode_attachment, topic_key
from fleetslam.msg.conversions import pose_matrix, pose_msg, pose_msgs
from fleetslam.msg.typesys import get_type, header, message_from_dict, ns_from_stamp, stamp_from_ns
from fleetslam.slam.node import CATCH_UP_SERVICE, CATCH_UP_TYPE, SlamNode, SlamNodeConfig

from ..middleware.conftest import plain_session
from ..support import wait_until

CAMERA = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
EPOCH = 4242


def _summary(agent: str, keyframe_id: int, epoch: int = EPOCH) -> KeyframeSummary:
    rng = np.random.default_rng(keyframe_id)
    keypoints = rng.uniform([0, 0], [319, 239], (60, 2))
    points = np.column_stack([np.zeros((60, 2)), rng.uniform(0.5, 4.0, 60)])
    descriptors = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    pose = np.eye(4)
    pose[0, 3] = 0.1 * keyframe_id
    return summarize(agent, keyframe_id, (1000 + keyframe_id) * 10**9, pose, CAMERA, keypoints, points, descriptors,
                     epoch=epoch)  # fmt: skip


def _message(summary: KeyframeSummary) -> Any:
    msg = message_from_dict("fleetslam_msgs/msg/KeyframeSummary", summary_fields(summary))
    msg.header, msg.pose = header("map", summary.stamp_ns), pose_msg(summary.pose)
    return msg


def _graph(agent: str, ids: list[int], sequence: int) -> Any:
    graph = get_type("fleetslam_msgs/msg/KeyframeGraph")(
        header=header("map", 0), agent=agent, keyframe_ids=np.asarray(ids, np.uint32),
        poses=pose_msgs([_summary(agent, i).pose for i in ids]), stamps=[stamp_from_ns(i * 10**9) for i in ids],
        constraints=[], optimized=False, sequence=sequence, full=False, epoch=EPOCH,
    )  # fmt: skip
    return graph


def test_a_node_catches_up_on_a_peers_summaries_through_hostile_and_slow_answers(
    make_context: Callable[..., Context],
) -> None:
    collaboration = CollaborationConfig(catch_up_batch=4, catch_up_period=0.1, catch_up_grace=0.3,
                                        catch_up_timeout=1.0)  # fmt: skip
    slam = SlamNode(Node("slam", context=make_context("c3po")),
                    SlamNodeConfig(use_wheel_odometry=False, peers=["r2d2"], collaboration=collaboration))  # fmt: skip
    peer = Node("slam", context=make_context("r2d2"))
    store = SummaryStore(100, max_per_call=4)
    for i in range(10):
        store.add(_summary("r2d2", i))
    response_type = get_type(f"{CATCH_UP_TYPE}_Response")
    answers = ["wrong_agent", "malformed", "raise", "slow", "not_asked", "good"]
    asked: list[list[int]] = []

    def answer(request: Any) -> Any:
        ids = [int(i) for i in request.ids]
        asked.append(ids)
        kind = answers.pop(0) if len(answers) > 1 else answers[0]
        found, unknown = store.lookup(ids)
        summaries = [_message(s) for s in found]
        if kind == "wrong_agent":
            return response_type(agent="c3po", epoch=EPOCH, summaries=summaries, unknown=np.zeros(0, np.uint32))
        if kind == "malformed":
            summaries[0].depth_mm = np.zeros_like(summaries[0].depth_mm)  # a feature without depth
            summaries[1].intrinsics = np.array([np.nan, 1.0, 1.0, 1.0])
            summaries[2].pose.orientation.w = 0.0  # not a rotation
            summaries[2].pose.orientation.z = 0.0
            summaries[3].agent = "c3po"
            return response_type(
                agent="r2d2", epoch=EPOCH, summaries=summaries, unknown=np.arange(1000, 10**5, dtype=np.uint32)
            )
        if kind == "raise":
            raise RuntimeError("the peer's handler failed")
        if kind == "slow":
            time.sleep(1.5)  # past the caller's timeout
        if kind == "not_asked":  # summaries of keyframes not asked for, and of another run
            others = [_message(_summary("r2d2", 50)), _message(_summary("r2d2", ids[0], epoch=1))]
            return response_type(agent="r2d2", epoch=EPOCH, summaries=others, unknown=np.zeros(0, np.uint32))
        return response_type(agent="r2d2", epoch=EPOCH, summaries=summaries, unknown=np.asarray(unknown, np.uint32))

    peer.create_service(CATCH_UP_TYPE, CATCH_UP_SERVICE, answer)
    updates = peer.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph_updates", QoSProfile(depth=50))
    summaries = peer.create_publisher("fleetslam_msgs/msg/KeyframeSummary", "keyframe_summaries", QoSProfile(depth=50))
    assert wait_until(lambda: updates.matched_subscriptions > 0 and summaries.matched_subscriptions > 0, 10.0)
    summaries.publish(_message(_summary("r2d2", 0)))  # keyframe 0 arrives on the stream, the others do not
    updates.publish(_graph("r2d2", [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 12], 1))  # 12: the peer no longer keeps it
    state = slam.linker.peer("r2d2").catch_up
    assert wait_until(lambda: state.caught_up == set(range(1, 10)) and 12 in state.unavailable, 30.0), (
        asked, slam.counts, state)  # fmt: skip
    assert 0 not in state.caught_up and 0 in state.received
    assert all(len(ids) <= 4 for ids in asked) and all(0 not in ids for ids in asked)
    assert slam.counts["catch_up_failures"] >= 4  # wrong agent, malformed (4 bad of 4), raised, too slow
    assert slam.counts["bad_peer_messages"] >= 4
    assert slam.counts["caught_up_summaries"] == 9
    queued = {s.keyframe_id: s for s in slam.linker.queue}
    assert sorted(queued) == list(range(10))
    np.testing.assert_array_equal(queued[7].descriptors, store.lookup([7])[0][0].descriptors)
    np.testing.assert_allclose(queued[7].pose, _summary("r2d2", 7).pose)
    requests_done = len(asked)
    time.sleep(1.0)
    assert len(asked) == requests_done  # caught up: nothing more is asked


def test_a_node_answers_its_summaries_and_shrugs_off_hostile_requests(
    make_context: Callable[..., Context], router_endpoint: str
) -> None:
    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig(use_wheel_odometry=False))
    for i in range(20):
        slam.summary_store.add(_summary("c3po", i, epoch=slam.graph_writer.epoch))
    client = Node("peer", context=make_context("r2d2")).create_client(CATCH_UP_TYPE, f"/c3po/{CATCH_UP_SERVICE}")
    request = get_type(f"{CATCH_UP_TYPE}_Request")
    assert client.wait_for_service(5.0)

    # Hostile requests: garbage bytes, truncated CDR, a length that lies, no attachment; each answered with an
    # error at once or ignored, none kills the service.
    attacker = plain_session(router_endpoint)
    key = topic_key(0, f"/c3po/{CATCH_UP_SERVICE}", CATCH_UP_TYPE)
    valid = bytes(np.asarray([0, 1, 0, 0, 3, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0], np.uint8))
    payloads = [b"", b"\x00\x01", np.random.default_rng(0).bytes(300), valid[:10],
                valid[:4] + (0x7FFFFFFF).to_bytes(4, "little") + valid[8:]]  # fmt: skip
    try:
        # A fresh session learns of the service a moment after it connects.
        assert wait_until(lambda: bool(list(attacker.get(key, payload=b"", timeout=1.0))), 10.0)
        for n, payload in enumerate(payloads * 4):
            attachment = None if n % 5 == 4 else encode_attachment(n + 1, time.time_ns(), bytes(16))
            started = time.monotonic()
            replies = list(attacker.get(key, payload=payload, attachment=attachment, timeout=5.0,
                                        target=zenoh.QueryTarget.ALL_COMPLETE))  # fmt: skip
            assert time.monotonic() - started < 4.0
            assert len(replies) == 1 and replies[0].ok is None  # an error, not a hang
    finally:
        attacker.close()
    # An oversized request (a million ids) is answered for its first ids only, quickly.
    started = time.monotonic()
    huge = client.call(request(ids=np.arange(1_000_000, dtype=np.uint32)[::-1].copy()), timeout=10.0)
    assert time.monotonic() - started < 5.0
    assert len(huge.summaries) == 0 and len(huge.unknown) == MAX_REQUEST_IDS  # the first 256 asked are all unknown
    # Requests the workers of several peers make at once still get their answers.
    answers: list[Any] = []

    def ask() -> None:
        answers.append(client.call(request(ids=np.array([3, 19, 500, 3], np.uint32)), timeout=10))

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(15.0)
    assert len(answers) == 4
    answer = answers[0]
    assert (answer.agent, answer.epoch) == ("c3po", slam.graph_writer.epoch)
    assert [int(s.id) for s in answer.summaries] == [3, 19] and list(answer.unknown) == [500]
    got = summary_from_message(answer.summaries[1], pose_matrix(answer.summaries[1].pose),
                               ns_from_stamp(answer.summaries[1].header.stamp))  # fmt: skip
    sent = _summary("c3po", 19, epoch=slam.graph_writer.epoch)
    np.testing.assert_array_equal(got.descriptors, sent.descriptors)
    np.testing.assert_allclose(got.keypoints, sent.keypoints)
    np.testing.assert_allclose(got.pose, sent.pose, atol=1e-9)
    assert got.stamp_ns == sent.stamp_ns and got.epoch == sent.epoch
    # At most a few per call however many are asked.
    many = client.call(request(ids=np.arange(20, dtype=np.uint32)), timeout=10.0)
    assert [int(s.id) for s in many.summaries] == list(range(slam.config.collaboration.catch_up_batch))


def test_catch_up_can_be_turned_off(make_context: Callable[..., Context]) -> None:
    config = SlamNodeConfig(use_wheel_odometry=False, peers=["r2d2"], collaboration=CollaborationConfig(catch_up=False))
    slam = SlamNode(Node("slam", context=make_context("c3po")), config)
    assert slam._catch_up_thread is None and "r2d2" in slam._summary_clients
