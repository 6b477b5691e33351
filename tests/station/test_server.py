"""The console's server with a real router, a real robot node and a WebSocket client."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any

import pytest

from fleetslam.middleware import Context
from fleetslam.station.protocol import TeleopLimits
from fleetslam.station.server import StationServer

from ..support import wait_until
from .conftest import RobotUnderTest

aiohttp = pytest.importorskip("aiohttp")


async def _session(url: str, actions: Callable[[Any, list[dict[str, Any]]], Any]) -> list[dict[str, Any]]:
    received: list[dict[str, Any]] = []
    async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws:

        async def reader() -> None:
            async for frame in ws:
                received.append(json.loads(frame.data))

        task = asyncio.create_task(reader())
        await actions(ws, received)
        task.cancel()
    return received


def test_console_streams_map_camera_and_drives(
    make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    limits = TeleopLimits(max_linear=0.4, max_angular=1.0)
    with StationServer(make_context(), port=0, limits=limits) as server:

        async def actions(ws: Any, received: list[dict[str, Any]]) -> None:
            await ws.send_str(json.dumps({"type": "select", "agent": "c3po"}))
            for _ in range(60):
                kinds = {m["type"] for m in received}
                if {"voxels", "image", "pose"} <= kinds:
                    break
                await asyncio.sleep(0.1)
            await ws.send_str(json.dumps({"type": "ping", "t": 1.5}))
            start = time.monotonic()
            while time.monotonic() - start < 0.6:  # hold the deadman and W for 0.6 s
                await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 1.0, "w": 0.0, "deadman": True}))
                await asyncio.sleep(0.05)
            await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0, "w": 0, "deadman": False}))
            await asyncio.sleep(0.5)
            await ws.send_str(json.dumps({"type": "estop", "agent": "c3po", "engage": True}))
            for _ in range(50):
                if any(m["type"] == "estop" for m in received):
                    break
                await asyncio.sleep(0.1)

        received = asyncio.run(_session(server.ws_url, actions))
    kinds = [m["type"] for m in received]
    assert (kinds[0] == "hello" and "c3po" in received[0]["agents"]) or any(
        m["type"] == "agents" and "c3po" in m["agents"] for m in received
    )
    voxels = [m for m in received if m["type"] == "voxels" and m["agent"] == "c3po"]
    assert voxels and voxels[-1]["total"] > 0
    # Incremental: later updates carry only the new voxels, not the whole map again.
    if len(voxels) > 1:
        assert len(voxels[-1]["add"]) < voxels[-1]["total"]
    images = [m for m in received if m["type"] == "image"]
    assert images and images[0]["mime"] == "image/jpeg" and images[-1]["seq"] > images[0]["seq"] - 1
    assert any(m["type"] == "pong" and m["t"] == 1.5 for m in received)
    assert any(m["type"] == "pose" and m["agent"] == "c3po" for m in received)
    estop = next(m for m in received if m["type"] == "estop")
    assert estop["ok"] and test_robot.estop_requests == [True]
    moving = [c for c in test_robot.commands if c[1] != 0.0]
    assert moving and all(abs(v - 0.4) < 1e-9 for _, v, _ in moving)  # clamped to the console's limit: exactly 0.4
    last_moving = moving[-1][0]
    stops = [c for c in test_robot.commands if c[1] == 0.0 and c[0] >= last_moving]
    assert stops, "no zero command after the deadman was released"


def test_disconnect_while_driving_stops(make_context: Callable[..., Context], test_robot: RobotUnderTest) -> None:
    with StationServer(make_context(), port=0) as server:

        async def actions(ws: Any, received: list[dict[str, Any]]) -> None:
            for _ in range(10):
                await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0.3, "w": 0.2, "deadman": True}))
                await asyncio.sleep(0.05)

        asyncio.run(_session(server.ws_url, actions))
        closed_at = time.time()
        # A disconnect releases at once: the zero goes out on the next 50 ms tick (it may precede `closed_at`), and
        # 0.2 s leaves three more ticks for a loaded machine.
        assert wait_until(lambda: any(c[1] == 0.0 and c[0] >= closed_at - 0.05 for c in test_robot.commands), 2.0)
        time.sleep(0.5)
        late = [c for c in test_robot.commands if c[0] > closed_at + 0.2 and c[1] != 0.0]
        assert not late


async def _handshake(url: str, headers: dict[str, str]) -> tuple[int, str]:
    """Status of a WebSocket upgrade request (101: accepted) and the refusal's text."""
    async with aiohttp.ClientSession() as http:
        try:
            async with http.ws_connect(url, headers=headers) as ws:
                await ws.close()
                return 101, ""
        except aiohttp.WSServerHandshakeError as err:
            return err.status, err.message


def test_websocket_refuses_foreign_origins_and_missing_or_wrong_tokens(
    make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    """Issue 18: the console's WebSocket accepted a connection claiming Origin http://evil.example and drove c3po."""
    with StationServer(make_context(), port=0) as server:
        own = f"http://{server.host}:{server.port}"
        plain = f"ws://{server.host}:{server.port}/ws"
        refused = {
            "foreign page with the token": (server.ws_url, {"Origin": "http://evil.example"}),
            "DNS rebinding (own origin, no token)": (
                plain,
                {"Origin": "http://evil.example:80", "Host": "evil.example:80"},
            ),
            "own origin, no token": (plain, {"Origin": own}),
            "own origin, wrong token": (plain + "?token=" + "x" * 22, {"Origin": own}),
            "program, no token": (plain, {}),
        }
        for what, (url, headers) in refused.items():
            assert asyncio.run(_handshake(url, headers))[0] == 403, what
        assert server.refused == len(refused)

        async def drive(ws: Any, received: list[dict[str, Any]]) -> None:
            await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0.2, "w": 0.0, "deadman": True}))
            await asyncio.sleep(1.0)
            await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0.0, "w": 0.0, "deadman": False}))

        assert not any(v for _, v, _ in test_robot.commands)  # nothing reached the robot from the refused ones
        for headers in ({"Origin": own}, {}):  # the console's page, and a program with the token
            assert asyncio.run(_handshake(server.ws_url, headers))[0] == 101
        asyncio.run(_session(server.ws_url, drive))
        assert wait_until(lambda: any(v > 0.05 for _, v, _ in test_robot.commands), 5.0)
