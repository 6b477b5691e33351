"""Fixtures for every test: a real Zenoh router on a free loopback port, and contexts connected to it."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from fleetslam.middleware import Context, Router

from .support import free_port

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

os.environ.setdefault("MUJOCO_GL", "egl")

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    # Started in the background of a non-interactive shell (`cmd &`, nohup), the suite inherits Ctrl-C ignored,
    # and so would every process it starts: the tests of Ctrl-C (a router, a node, a launch stopping on SIGINT)
    # would test the shell instead. Python's own handler puts them back as a terminal starts them.
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def _seeded_opencv() -> None:
    """Every test starts from the same OpenCV RNG state (thread-local; the calling thread's), so a test's result
    does not depend on which tests ran before it. Our own RANSAC calls are deterministic already (OpenCV's
    solvePnPRansac seeds its own generator; loop verification seeds before each call)."""
    try:
        import cv2
    except ImportError:
        return
    cv2.setRNGSeed(0)


@pytest.fixture
def shared_data() -> Path:
    """`../shared/data` beside the checkout; tests needing it skip when a plain clone lacks it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared reference data not found at {SHARED_DATA} (present in CI beside the checkout)")
    return SHARED_DATA


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


@pytest.fixture
def fleet_env(router_endpoint: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """Environment of a process joining the test router (as the CLI tools read it)."""
    monkeypatch.setenv("FLEETSLAM_ROUTER", router_endpoint)
    monkeypatch.setenv("FLEETSLAM_LISTEN", "tcp/127.0.0.1:0")
    monkeypatch.delenv("FLEETSLAM_AGENT", raising=False)
    return router_endpoint
