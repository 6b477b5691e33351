"""A real Zenoh router on a free loopback port, and contexts connected to it (multicast off)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator

import pytest

from fleetslam.middleware import Context, Router


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def router_endpoint() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]):
        yield endpoint


@pytest.fixture
def make_context(router_endpoint: str) -> Iterator[Callable[..., Context]]:
    contexts: list[Context] = []

    def make(namespace: str = "/", **kwargs: object) -> Context:
        ctx = Context(
            router=router_endpoint,
            listen="tcp/127.0.0.1:0",
            namespace=namespace,
            environ={},
            **kwargs,  # type: ignore[arg-type]
        )
        contexts.append(ctx)
        return ctx

    yield make
    for ctx in contexts:
        ctx.close()


def wait_until(predicate: Callable[[], bool], timeout_s: float = 5.0, interval_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return predicate()
