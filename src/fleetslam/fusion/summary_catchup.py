"""Keyframe summaries that a peer missed (its link was down, it joined late), kept by the sender and asked for by
the receiver in small batches.

``keyframe_summaries`` is a best-effort stream: a summary sent while the link to a peer is down is lost, and
without it the peer can never recognise the places this agent saw meanwhile. The keyframe graph is not lost (it is
numbered, and a reader that sees a gap asks for the whole graph), so after a reconnection the receiver knows every
keyframe the sender made and can tell which of them came without a summary.

- :class:`SummaryStore` (sender): the summaries of this agent's newest keyframes, at most ``capacity`` (the oldest
  leave first), answered by id, at most ``max_per_call`` per request.
- :class:`SummaryCatchUp` (receiver, one per peer): which of the peer's keyframes in this agent's mirror of its
  graph have had no summary for ``grace_s`` (one in flight on the stream is not asked for), and which to ask next:
  at most ``batch`` ids per request, one request at a time, at most one every ``period_s``, and none while the
  recognition queue has no ``room`` for them. A request that fails (a dead link: the call timed out) doubles the
  wait, up to ``backoff_max_s``. Ids the peer answers it no longer keeps are not asked again.

Pure: no middleware, no threads of its own (both classes are thread-safe: the middleware's callbacks and the
node's catch-up thread share them). Times are seconds of a monotonic clock, passed in.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field

from fleetslam.fusion.keyframe_summary import KeyframeSummary

MAX_REQUEST_IDS = 256
"""A request naming more ids is answered for its first ones only (a hostile one could name millions)."""


def summary_nbytes(summary: KeyframeSummary) -> int:
    """Bytes of a summary's arrays (keypoints, depth, descriptors, pose): what a stored one costs, less the
    Python objects around them (~1 kB)."""
    return int(summary.keypoints.nbytes + summary.depth.nbytes + summary.descriptors.nbytes + summary.pose.nbytes)


class SummaryStore:
    """This agent's newest keyframe summaries, by keyframe id (see the module docstring)."""

    def __init__(self, capacity: int = 1000, *, max_per_call: int = 8) -> None:
        if capacity < 1 or max_per_call < 1:
            raise ValueError(f"capacity ({capacity}) and max_per_call ({max_per_call}) must be >= 1")
        self.capacity = capacity
        self.max_per_call = max_per_call
        self._summaries: OrderedDict[int, KeyframeSummary] = OrderedDict()
        self._nbytes = 0
        self._lock = threading.Lock()
        self.evicted = 0
        """Summaries that left the store to make room (a peer asking for them is told they are unknown)."""

    def __len__(self) -> int:
        return len(self._summaries)

    @property
    def nbytes(self) -> int:
        """Bytes of the stored summaries' arrays (:func:`summary_nbytes`)."""
        return self._nbytes

    def add(self, summary: KeyframeSummary) -> None:
        """Keep a summary (replacing one of the same id); the oldest leave beyond ``capacity``."""
        with self._lock:
            old = self._summaries.pop(summary.keyframe_id, None)
            if old is not None:
                self._nbytes -= summary_nbytes(old)
            self._summaries[summary.keyframe_id] = summary
            self._nbytes += summary_nbytes(summary)
            while len(self._summaries) > self.capacity:
                _, gone = self._summaries.popitem(last=False)
                self._nbytes -= summary_nbytes(gone)
                self.evicted += 1

    def lookup(self, ids: Sequence[int]) -> tuple[list[KeyframeSummary], list[int]]:
        """The summaries of the first ``max_per_call`` known ``ids`` (in the order asked), and the ids among the
        first :data:`MAX_REQUEST_IDS` asked that are not kept; the ids after the ``max_per_call``-th known one are
        in neither list (the caller asks again)."""
        found: list[KeyframeSummary] = []
        unknown: list[int] = []
        seen: set[int] = set()
        with self._lock:
            for keyframe_id in ids[:MAX_REQUEST_IDS]:
                keyframe_id = int(keyframe_id)
                if keyframe_id in seen:
                    continue
                seen.add(keyframe_id)
                summary = self._summaries.get(keyframe_id)
                if summary is None:
                    unknown.append(keyframe_id)
                elif len(found) < self.max_per_call:
                    found.append(summary)
        return found, unknown


@dataclass
class SummaryCatchUp:
    """What of one peer's keyframes this agent has no summary of, and what to ask the peer for next."""

    batch: int = 8
    """Ids per request (the peer answers at most its own ``max_per_call``; the rest are asked again)."""
    period_s: float = 0.5
    """Shortest time between two requests to the peer."""
    grace_s: float = 2.0
    """A keyframe is asked for once it has been in the mirror this long without a summary (the summary may still be
    on its way: the stream sends it before the graph update that names the keyframe)."""
    backoff_max_s: float = 8.0
    """Longest wait after failed requests (doubling from ``period_s``)."""
    epoch: int = 0
    """The peer's run the ids belong to (a new one forgets everything)."""
    received: set[int] = field(default_factory=set)
    """Keyframes whose summary arrived (on the stream or by catch-up)."""
    caught_up: set[int] = field(default_factory=set)
    """Keyframes whose summary arrived by catch-up."""
    unavailable: set[int] = field(default_factory=set)
    """Keyframes the peer said it no longer keeps (never asked again)."""
    requests: int = 0
    """Requests made."""
    failures: int = 0
    """Requests that failed (timed out, or a malformed answer)."""
    _first_seen: dict[int, float] = field(default_factory=dict)
    _in_flight: tuple[int, ...] = ()
    _next_at: float = 0.0
    _backoff_s: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def in_flight(self) -> tuple[int, ...]:
        """The ids of the request waiting for its answer (empty: none)."""
        return self._in_flight

    def observe_epoch(self, epoch: int) -> None:
        """The peer's run is ``epoch``: a new one (it restarted) forgets the old run's ids."""
        with self._lock:
            if epoch in (0, self.epoch):
                return
            self.epoch = epoch
            self.received.clear()
            self.caught_up.clear()
            self.unavailable.clear()
            self._first_seen.clear()
            self._in_flight = ()

    def summary_arrived(self, keyframe_id: int, *, by_catch_up: bool = False) -> None:
        """A summary of the peer's keyframe arrived (of the current run: the caller checks the epoch)."""
        with self._lock:
            self.received.add(int(keyframe_id))
            if by_catch_up:
                self.caught_up.add(int(keyframe_id))

    def missing(self, mirror_ids: Collection[int], now: float, *, limit: int | None = None) -> list[int]:
        """The keyframes in the mirror that have had no summary for ``grace_s``, not asked for now, in id order (the
        first ``limit`` of them)."""
        with self._lock:
            return self._missing(mirror_ids, now, limit)

    def _missing(self, mirror_ids: Collection[int], now: float, limit: int | None) -> list[int]:
        ids = mirror_ids if isinstance(mirror_ids, set | frozenset) else set(mirror_ids)
        candidates = ids - self.received - self.unavailable - set(self._in_flight)
        for keyframe_id in candidates - self._first_seen.keys():
            self._first_seen[keyframe_id] = now
        if len(self._first_seen) > 2 * max(len(candidates), 64):  # received since, or dropped from the peer's graph
            self._first_seen = {i: self._first_seen[i] for i in candidates}
        due = now - self.grace_s
        found: list[int] = []
        for keyframe_id in sorted(candidates):
            if self._first_seen[keyframe_id] <= due:
                found.append(keyframe_id)
                if limit is not None and len(found) >= limit:
                    break
        return found

    def next_request(self, mirror_ids: Collection[int], now: float, *, room: int | None = None) -> list[int]:
        """The ids to ask the peer for now ([] when none is missing, a request is in flight, it is too early, or
        ``room`` (what the recognition queue can take) is 0). The caller must report the outcome with
        :meth:`answered` or :meth:`failed`."""
        with self._lock:
            if self._in_flight or now < self._next_at:
                return []
            limit = self.batch if room is None else min(self.batch, room)
            if limit <= 0:
                return []
            ids = self._missing(mirror_ids, now, limit)
            if ids:
                self._in_flight = tuple(ids)
                self.requests += 1
            return ids

    def answered(self, arrived: Iterable[int], unknown: Iterable[int], now: float) -> None:
        """The request in flight was answered: ``arrived`` came (the caller also reports each with
        :meth:`summary_arrived`), ``unknown`` the peer no longer keeps; the other ids asked are asked again."""
        with self._lock:
            asked = set(self._in_flight)
            self.caught_up.update(i for i in arrived if i in asked)
            self.received.update(i for i in arrived if i in asked)
            self.unavailable.update(i for i in unknown if i in asked)
            self._in_flight = ()
            self._backoff_s = 0.0
            self._next_at = now + self.period_s

    def failed(self, now: float) -> None:
        """The request in flight failed (no answer in time, a malformed one): its ids are asked again, later."""
        with self._lock:
            self._in_flight = ()
            self.failures += 1
            self._backoff_s = min(self.backoff_max_s, max(self.period_s, 2 * self._backoff_s))
            self._next_at = now + self._backoff_s
