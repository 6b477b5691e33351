"""Summaries a peer missed: the sender keeps its newest ones (bounded, answered in small batches), the receiver
finds the keyframes of the peer's graph that came without one and asks for them at a bounded rate."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.datasets.base import Intrinsics
from fleetslam.fusion.collaboration import CollaborationConfig, InterAgentLinker
from fleetslam.fusion.graph_exchange import GraphUpdate
from fleetslam.fusion.keyframe_summary import KeyframeSummary, summarize
from fleetslam.fusion.summary_catchup import MAX_REQUEST_IDS, SummaryCatchUp, SummaryStore, summary_nbytes

CAMERA = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)


def _summary(agent: str, keyframe_id: int, *, features: int = 400, epoch: int = 7) -> KeyframeSummary:
    rng = np.random.default_rng(keyframe_id)
    keypoints = rng.uniform([0, 0], [319, 239], (features, 2))
    points = np.column_stack([np.zeros((features, 2)), rng.uniform(0.5, 4.0, features)])
    descriptors = rng.integers(0, 256, (features, 32), dtype=np.uint8)
    return summarize(agent, keyframe_id, keyframe_id * 10**9, np.eye(4), CAMERA, keypoints, points, descriptors,
                     epoch=epoch)  # fmt: skip


def test_the_store_keeps_the_newest_summaries_and_answers_a_few_per_call() -> None:
    store = SummaryStore(capacity=5, max_per_call=2)
    for i in range(8):
        store.add(_summary("r2d2", i))
    assert len(store) == 5 and store.evicted == 3
    # 400 features: 8 B keypoint, 4 B depth, 32 B descriptor, and the pose.
    assert store.nbytes == 5 * summary_nbytes(_summary("r2d2", 0)) == 5 * (400 * 44 + 128)
    found, unknown = store.lookup([1, 6, 6, 3, 4, 7, 99])
    assert [s.keyframe_id for s in found] == [6, 3]  # at most two; 4 and 7 are asked again
    assert unknown == [1, 99]  # evicted, never made
    store.add(_summary("r2d2", 6))  # the same id again replaces, does not grow
    assert len(store) == 5 and store.nbytes == 5 * (400 * 44 + 128)


def test_a_hostile_request_is_answered_for_its_first_ids_only() -> None:
    store = SummaryStore(capacity=3, max_per_call=8)
    store.add(_summary("r2d2", 1))
    found, unknown = store.lookup([*range(2, 1_000_000), 1])
    assert found == [] and len(unknown) == MAX_REQUEST_IDS  # id 1 comes after the first 256: not looked at
    with pytest.raises(ValueError, match="capacity"):
        SummaryStore(capacity=0)


def test_missing_keyframes_are_asked_for_in_batches_after_the_grace_period() -> None:
    catch_up = SummaryCatchUp(batch=3, period_s=0.5, grace_s=2.0)
    catch_up.observe_epoch(7)
    mirror = set(range(10))
    for i in (0, 1, 5):  # arrived on the stream
        catch_up.summary_arrived(i)
    assert catch_up.next_request(mirror, 100.0) == []  # first seen now: their summaries may still be on the way
    assert catch_up.missing(mirror, 101.9) == []
    assert catch_up.next_request(mirror, 102.0) == [2, 3, 4]
    assert catch_up.in_flight == (2, 3, 4)
    assert catch_up.next_request(mirror, 102.1) == []  # one request at a time
    assert catch_up.missing(mirror, 102.1) == [6, 7, 8, 9]
    catch_up.answered([2, 4, 55], [3], 102.2)  # 55 was not asked: ignored; 3 the peer no longer keeps
    assert catch_up.caught_up == {2, 4} and catch_up.unavailable == {3} and 55 not in catch_up.received
    assert catch_up.next_request(mirror, 102.5) == []  # period
    assert catch_up.next_request(mirror, 102.7, room=2) == [6, 7]  # no more than the queue can take
    catch_up.answered([6, 7], [], 102.8)
    assert catch_up.next_request(mirror, 103.3, room=0) == []
    assert catch_up.next_request(mirror | {10}, 103.3) == [8, 9]  # 10 is new: not yet
    assert catch_up.requests == 3


def test_failed_requests_back_off_and_are_asked_again() -> None:
    catch_up = SummaryCatchUp(batch=2, period_s=0.5, grace_s=0.0, backoff_max_s=4.0)
    mirror = {1, 2}
    now = 0.0
    assert catch_up.next_request(mirror, now) == [1, 2]
    for wait in (0.5, 1.0, 2.0, 4.0, 4.0):  # doubling from the period, up to the longest wait
        catch_up.failed(now)
        assert catch_up.next_request(mirror, now + wait - 0.01) == []
        now += wait
        assert catch_up.next_request(mirror, now) == [1, 2]
    assert catch_up.failures == 5
    catch_up.answered([1, 2], [], now)
    assert catch_up.missing(mirror, now + 1.0) == [] and catch_up.next_request(mirror, now + 1.0) == []
    assert catch_up.next_request(mirror | {3}, now + 0.49) == []  # after an answer: the period again
    assert catch_up.next_request(mirror | {3}, now + 0.5) == [3]


def test_a_restarted_peer_forgets_the_old_runs_ids() -> None:
    catch_up = SummaryCatchUp(grace_s=0.0)
    catch_up.observe_epoch(1)
    catch_up.summary_arrived(1)
    catch_up.next_request({1, 2}, 0.0)
    catch_up.observe_epoch(2)
    assert catch_up.received == set() and catch_up.in_flight == ()
    assert catch_up.next_request({1, 2}, 0.0) == [1, 2]


def _update(sequence: int, ids: range, epoch: int = 7, *, full: bool = False) -> GraphUpdate[object]:
    return GraphUpdate(sequence, full, {i: np.eye(4) for i in ids}, {i: float(i) for i in ids}, [], epoch)


def test_the_linker_asks_for_what_its_mirror_names_without_a_summary() -> None:
    config = CollaborationConfig(catch_up_batch=4, catch_up_grace=1.0, catch_up_period=0.5, max_queued=16)
    linker = InterAgentLinker("c3po", config)
    linker.apply_graph("r2d2", _update(1, range(3)))
    for i in range(3):
        linker.queue_summary(_summary("r2d2", i, features=30))
    # The link drops: keyframes 3..9 are made without this agent hearing of them; a gap, then the full graph.
    assert not linker.apply_graph("r2d2", _update(5, range(9, 10)))
    assert linker.catch_up_request("r2d2", 10.0) == (7, [])  # out of sync: not before the full graph
    assert linker.apply_graph("r2d2", _update(5, range(10), full=True))
    assert linker.catch_up_request("r2d2", 10.0) == (7, [])  # grace
    epoch, ids = linker.catch_up_request("r2d2", 11.0)
    assert (epoch, ids) == (7, [3, 4, 5, 6])
    answer = [_summary("r2d2", i, features=30) for i in (3, 4)] + [_summary("r2d2", 5, features=30, epoch=99)]
    answer.append(_summary("c3po", 6, features=30))  # names another agent: not taken
    assert linker.catch_up_answered("r2d2", answer, [], 11.1) == 2
    assert [s.keyframe_id for s in linker.queue] == [0, 1, 2, 3, 4]
    # The queue holds 5 of 16: room for three more (half the queue is for catch-up).
    assert linker.catch_up_request("r2d2", 11.6) == (7, [5, 6, 7])
    linker.catch_up_failed("r2d2", 11.7)
    assert linker.catch_up_request("r2d2", 12.0) == (7, [])  # backing off
    linker.queue.clear()
    assert linker.catch_up_request("r2d2", 12.3)[1] == [5, 6, 7, 8]
    state = linker.peers["r2d2"].catch_up
    assert state.caught_up == {3, 4} and state.received == {0, 1, 2, 3, 4} and state.failures == 1
    off = InterAgentLinker("c3po", CollaborationConfig(catch_up=False, catch_up_grace=0.0))
    off.apply_graph("r2d2", _update(1, range(3)))
    assert off.catch_up_request("r2d2", 10.0) == (7, [])
