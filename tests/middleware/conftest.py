"""Middleware test fixtures on top of tests/conftest.py's router: a plain Zenoh session as an independent observer.

``raw_session`` is an eclipse-zenoh session that knows nothing of fleetslam: it checks keys, attachments and
tokens as any rmw_zenoh peer would see them, and injects hand-made samples (sequence gaps, bad payloads).
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
import zenoh


def plain_session(router_endpoint: str) -> zenoh.Session:
    """A bare Zenoh peer connected to the test router (multicast off, loopback only)."""
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([router_endpoint]))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/delay", "0")
    return zenoh.open(config)


@pytest.fixture
def raw_session(router_endpoint: str) -> Iterator[zenoh.Session]:
    session = plain_session(router_endpoint)
    yield session
    session.close()
