"""Fetching an agent's whole keyframe graph (``graph/full``) when its stream of deltas has a gap.

Graph updates are deltas (:mod:`fleetslam.fusion.graph_exchange`); a reader that missed one (a lost message, a late
start, a link cut) asks the writer for its whole graph. The SLAM node asks its peers, the mapping node its own
SLAM, the fleet back-end every agent. A service call blocks for up to its timeout, so it runs on a thread of its own,
never on the middleware's or the executor's, and one request per agent is under way at a time: the gaps a burst of
lost messages shows are answered by one whole graph, not by one each.

The fetcher is given its node's ``create_client`` (it does not import the middleware: the layering rule).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from fleetslam.msg.typesys import get_type

log = logging.getLogger(__name__)

GET_GRAPH_TYPE = "fleetslam_msgs/srv/GetGraph"


class GraphFetcher:
    """Whole-graph requests to agents, each on a thread of its own, one per agent at a time.

    ``on_graph(agent, graph)`` runs on the request's thread with the response's ``fleetslam_msgs/KeyframeGraph``;
    it must hand the graph to its node thread-safely. A failed request (the agent gone or slow, a malformed answer,
    an exception in ``on_graph``) is logged; the next gap asks again.
    """

    def __init__(
        self,
        create_client: Callable[[str, str], Any],
        on_graph: Callable[[str, Any], None],
        *,
        name: str,
        timeout: float = 5.0,
    ) -> None:
        self.name = name
        """Who fetches (the node's name), for its threads' names and the log."""
        self.timeout = timeout
        """Seconds a request waits for its answer."""
        self._create_client = create_client
        self._on_graph = on_graph
        self._clients: dict[str, Any] = {}
        self._in_flight: set[str] = set()
        self._lock = threading.Lock()

    def add(self, agent: str, service: str | None = None) -> None:
        """Make ``agent``'s graph fetchable, from ``service`` (default ``/<agent>/graph/full``)."""
        if agent not in self._clients:
            self._clients[agent] = self._create_client(GET_GRAPH_TYPE, service or f"/{agent}/graph/full")

    def request(self, agent: str) -> bool:
        """Ask ``agent`` for its whole graph unless a request to it is under way (or it was never added);
        whether a request started."""
        with self._lock:
            if agent in self._in_flight or agent not in self._clients:
                return False
            self._in_flight.add(agent)
        threading.Thread(target=self._fetch, args=(agent,), name=f"{self.name}/graph-{agent}", daemon=True).start()
        return True

    def in_flight(self, agent: str) -> bool:
        """Whether a request to ``agent`` is under way."""
        with self._lock:
            return agent in self._in_flight

    def _fetch(self, agent: str) -> None:
        try:
            response = self._clients[agent].call(get_type(f"{GET_GRAPH_TYPE}_Request")(), timeout=self.timeout)
            self._on_graph(agent, response.graph)
        except Exception as err:  # an agent gone, slow or answering nonsense: the next gap asks again
            log.info("%s: %s's whole graph could not be fetched: %s", self.name, agent, err)
        finally:
            with self._lock:
                self._in_flight.discard(agent)
