"""The console's server with a real router, a real robot node and a WebSocket client."""

from __future__ import annotations

import asyncio
import functools
import json
import time
from collections.abc import Callable
from typing import Any

import pytest

from fleetslam.middleware import Context
from fleetslam.station.protocol import TeleopLimits, decode_voxels
from fleetslam.station.server import BULK_TYPES, StationServer

from ..support import wait_until
from .conftest import RobotUnderTest

aiohttp = pytest.importorskip("aiohttp")


async def _session(url: str, actions: Callable[[Any, list[dict[str, Any]]], Any]) -> list[dict[str, Any]]:
    """A WebSocket client as the page is: it acknowledges the bulk streams it has handled."""
    received: list[dict[str, Any]] = []
    async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws:

        async def reader() -> None:
            handled = 0
            async for frame in ws:
                if frame.type == aiohttp.WSMsgType.BINARY:
                    header, add, remove = decode_voxels(frame.data)
                    received.append({**header, "added": add, "removed": remove})
                    handled += len(frame.data)
                else:
                    received.append(json.loads(frame.data))
                    handled += len(frame.data) if received[-1]["type"] in BULK_TYPES else 0
                await ws.send_str(json.dumps({"type": "ack", "bytes": handled}))

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
        assert voxels[-1]["add"] == len(voxels[-1]["added"]) < voxels[-1]["total"]
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


def test_a_release_stops_at_once_not_at_the_next_tick(
    make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    """The stream ticks every 4 s here: the deadman's release and a disconnect each publish their zero at once."""
    with StationServer(make_context(), port=0, teleop_rate_hz=0.25) as server:
        released_at: list[float] = []

        async def hold_then(release: bool, ws: Any, received: list[dict[str, Any]]) -> None:
            start = time.time()
            while not any(c[1] != 0.0 and c[0] >= start for c in test_robot.commands):  # a tick sent the drive
                await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0.3, "w": 0.0, "deadman": True}))
                await asyncio.sleep(0.05)
                assert time.time() - start < 10.0, "no drive command within two ticks"
            released_at.append(time.time())
            if release:
                await ws.send_str(json.dumps({"type": "drive", "agent": "c3po", "v": 0, "w": 0, "deadman": False}))
                await asyncio.sleep(1.5)  # stays connected: only the release can have sent the zero

        for release in (True, False):  # released by the deadman, then by closing the connection
            asyncio.run(_session(server.ws_url, functools.partial(hold_then, release)))
            # The release came just after a tick (the one that sent the drive), so the next is ~4 s away.
            assert wait_until(lambda: any(c[1] == 0.0 and c[0] >= released_at[-1] for c in test_robot.commands), 1.5), (
                f"no zero within 1.5 s of the release ({'deadman' if release else 'disconnect'})"
            )


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


def test_a_page_that_falls_behind_gets_pongs_at_once_and_the_newest_data_after(
    make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    """Issue 15: a busy page's pongs queued behind images and maps (the link read "lost" while all was well). A page
    that acknowledges nothing gets at most the bulk window, its pongs at once, and then only the newest frames."""
    window = 16 * 1024  # a dozen of the test robot's frames
    with StationServer(make_context(), port=0, bulk_window=window) as server:

        async def run() -> tuple[int, float, list[int], list[int]]:
            bulk, pong_after = 0, -1.0
            async with aiohttp.ClientSession() as http, http.ws_connect(server.ws_url) as ws:
                await ws.send_str(json.dumps({"type": "select", "agent": "c3po"}))
                seqs: list[int] = []

                async def read_for(seconds: float) -> None:
                    nonlocal bulk, pong_after
                    end = time.monotonic() + seconds
                    while (left := end - time.monotonic()) > 0:
                        try:
                            frame = await ws.receive(timeout=left)
                        except TimeoutError:
                            return
                        if frame.type == aiohttp.WSMsgType.BINARY:
                            bulk += len(frame.data)
                            continue
                        message = json.loads(frame.data)
                        if message["type"] == "pong":
                            pong_after = time.monotonic() - message["t"]
                        elif message["type"] in BULK_TYPES:
                            bulk += len(frame.data)
                            if message["type"] == "image":
                                seqs.append(message["seq"])

                await read_for(4.0)  # 40 frames published, a dozen sent: nothing acknowledged
                before_ack = list(seqs)
                await ws.send_str(json.dumps({"type": "ping", "t": time.monotonic()}))
                await read_for(1.0)
                withheld = bulk
                await ws.send_str(json.dumps({"type": "ack", "bytes": bulk}))
                await read_for(1.0)
                return withheld, pong_after, before_ack, seqs[len(before_ack) :]

        withheld, pong_after, before_ack, after_ack = asyncio.run(run())
    assert test_robot.frames > 30
    image_size = 4 * 1024  # a 160×120 JPEG of the test robot's frames, base64, is well under this
    assert window <= withheld <= window + image_size, withheld
    assert 0 <= pong_after < 0.5, pong_after
    assert after_ack and after_ack[0] > before_ack[-1] + 1, (before_ack, after_ack)  # stale frames were dropped
