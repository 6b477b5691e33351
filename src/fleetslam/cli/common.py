"""Helpers shared by the CLI commands that join the fleet: one context, one node, readable output."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import yaml

from fleetslam.middleware import Context, Node


@contextlib.contextmanager
def cli_node(name: str, *, statistics: bool = False, namespace: str = "/") -> Iterator[Node]:
    """A context and an anonymous-ish tool node (``_fleetslam_<name>_<pid>``) for the duration of a command."""
    import os

    with (
        Context(statistics=statistics) as ctx,
        Node(f"_fleetslam_{name}_{os.getpid()}", context=ctx, namespace=namespace, statistics_period_s=0) as node,
    ):
        yield node


def wait_for_graph(node: Node, predicate: Callable[[], bool], timeout_s: float = 1.0) -> bool:
    """Give discovery a moment (tokens arrive asynchronously) until ``predicate`` holds."""
    return node.context.graph.wait_for(lambda _: predicate(), timeout_s)


def to_yaml(data: Any) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False, width=120)


def stop_on_sigterm() -> threading.Event:
    """An event SIGTERM sets (a supervisor's or systemd's stop), so that a command ends as on Ctrl-C. Signals reach
    the main thread only: called on another (a test running the command), it only makes the event."""
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return stop


def wait_until_stopped(stop: threading.Event, duration: float | None = None) -> None:
    """Block until ``stop`` is set (SIGTERM), Ctrl-C, or ``duration`` seconds passed (None: no limit)."""
    deadline = None if duration is None else time.monotonic() + duration
    with contextlib.suppress(KeyboardInterrupt):
        while not stop.wait(0.2) and (deadline is None or time.monotonic() < deadline):
            pass


def settle(seconds: float = 0.3) -> None:
    """Let discovery settle before publishing from a fresh session."""
    time.sleep(seconds)


def run_adapter_node(
    args: Any,
    name: str,
    parameters: type[Any],
    adapter: Callable[[Node, Any], Any],
    *,
    namespace: str | None = None,
) -> int:
    """Run one node until Ctrl-C: a context from the environment, the node with its typed parameters from
    ``--config``/``--set``/``--ros-args``, and the adapter object that does the work (mapping, SLAM, fleet map)."""
    with Context() as ctx:
        node = Node(
            name, context=ctx, namespace=namespace, parameters=parameters, parameter_file=args.config,
            parameter_overrides=args.set, ros_args=getattr(args, "ros_args", None),
        )  # fmt: skip
        with node:
            adapter(node, node.parameters)
            print(f"{name} node {node.fq_name} running (Ctrl-C to stop)", flush=True)
            with contextlib.suppress(KeyboardInterrupt):
                node.spin()
    return 0
