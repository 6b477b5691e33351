"""The SLAM node's frame queue: colour and depth paired by stamp, the newest pair handed out, every frame counted."""

from __future__ import annotations

import threading

from fleetslam.slam.frame_queue import FrameQueue


def test_pairs_by_stamp_and_hands_out_the_newest_pair_dropping_the_stale_one() -> None:
    queue = FrameQueue(max_pending=4)
    queue.put_rgb(1, "rgb1")
    queue.put_depth(2, "depth2")  # arrives before its colour image
    queue.put_depth(1, "depth1")
    queue.put_rgb(2, "rgb2")  # pair 2 completes while pair 1 waits: pair 1 is stale
    pair = queue.take(timeout_s=0.0)
    assert pair is not None and (pair.stamp_ns, pair.rgb, pair.depth) == (2, "rgb2", "depth2")
    assert queue.take(timeout_s=0.0) is None
    assert (queue.received, queue.dropped, queue.pending) == (2, 1, 0)


def test_far_future_stamps_cannot_hold_the_queue() -> None:
    queue = FrameQueue(max_pending=2)
    for k in range(5):  # colour images stamped far in the future, never paired
        queue.put_rgb(10**18 + k, f"bogus{k}")
    queue.put_rgb(100, "rgb")
    queue.put_depth(100, "depth")
    pair = queue.take(timeout_s=0.0)
    assert pair is not None and pair.stamp_ns == 100
    # Evicted in arrival order: only the last two bogus halves wait; the rest were dropped and counted.
    assert queue.dropped == 4 and queue.pending == 1 and queue.received == 6


def test_take_waits_for_a_pair_and_close_wakes_the_consumer() -> None:
    queue = FrameQueue()
    threading.Timer(0.05, lambda: (queue.put_rgb(7, "r"), queue.put_depth(7, "d"))).start()
    pair = queue.take(timeout_s=5.0)
    assert pair is not None and pair.stamp_ns == 7
    threading.Timer(0.05, queue.close).start()
    assert queue.take(timeout_s=5.0) is None
