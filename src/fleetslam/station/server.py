"""The operator console's web server: static front end, WebSocket to browsers, teleop stream at a fixed rate.

Runs an asyncio loop (aiohttp) in its own thread; the bridge node's callbacks hand messages to it through
``call_soon_threadsafe``. JavaScript dependencies are installed from the npm registry at setup
(`scripts/setup-frontend`) and served from ``static/vendor`` — the page works offline.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleetslam._imports import require
from fleetslam.middleware import Context
from fleetslam.station.access import ConsoleAccess
from fleetslam.station.bridge import StationBridge
from fleetslam.station.protocol import TeleopLimits, VoxelUpdate
from fleetslam.station.session import SessionBridge

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
VENDOR_FILES = ("three.module.js", "OrbitControls.js")


BULK_WINDOW = 256 * 1024
"""Bulk data (characters of text, bytes of binary messages) sent to a browser and not yet acknowledged: beyond it the
server waits, keeping only the newest of each stream, so a busy page never has more than this ahead of a pong."""
BULK_TYPES = frozenset({"image", "pose", "path", "keyframes", "stats", "voxels"})
"""Streams whose newer message replaces an unsent older one (voxels: merged into it)."""


@dataclass
class _Client:
    """A browser: what it watches, and what waits to be sent to it (control messages first, in order; then the bulk
    streams, newest only, the longest-waiting stream first)."""

    socket: Any
    agent: str | None = None
    camera: str = "rgb"
    driving: set[str] = field(default_factory=set)
    control: deque[str] = field(default_factory=deque)
    bulk: dict[tuple[str, ...], dict[str, Any] | VoxelUpdate] = field(default_factory=dict)
    sent: int = 0
    """Bulk characters and bytes sent."""
    acked: int = 0
    """Bulk characters and bytes the page says it has handled."""
    wake: asyncio.Event = field(default_factory=asyncio.Event)

    def queue(self, message: dict[str, Any]) -> None:
        kind = message.get("type")
        if kind not in BULK_TYPES:
            self.control.append(json.dumps(message))
        elif kind == "voxels":
            update = VoxelUpdate(
                str(message["agent"]), float(message["size"]), message["add"], message["remove"],
                int(message["total"]), bool(message.get("reset")),
            )  # fmt: skip
            pending = self.bulk.get(("voxels", update.agent))
            if isinstance(pending, VoxelUpdate) and not update.reset:
                pending.merge(update)
            else:
                self.bulk.pop(("voxels", update.agent), None)  # a reset goes to the back of the line
                self.bulk[("voxels", update.agent)] = update
        else:
            key = (str(kind), str(message.get("agent", "")), str(message.get("source", message.get("kind", ""))))
            self.bulk[key] = message  # an unsent older one is replaced, keeping its place in the line
        self.wake.set()


class StationServer:
    """HTTP + WebSocket server of the console.

    Args:
        context: middleware context (the bridge node joins the fleet through it).
        host, port: where to listen (port 0 picks a free one; see ``self.port`` after ``start``).
        limits: speed limits and command timeout for teleoperation.
        teleop_rate_hz: rate of the command stream to the robots.
        access: the token and origins the WebSocket accepts (see :mod:`fleetslam.station.access`); default: a new
            random token, the console's own origin only. ``url`` carries the token.
        bulk_window: bulk data a browser may have unacknowledged (see ``BULK_WINDOW``).
        session: review this finished run's directory instead of a live fleet (no ``context`` needed; see
            :mod:`fleetslam.station.session`).
    """

    def __init__(
        self,
        context: Context | None,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        limits: TeleopLimits | None = None,
        teleop_rate_hz: float = 20.0,
        access: ConsoleAccess | None = None,
        bulk_window: int = BULK_WINDOW,
        session: Path | None = None,
    ) -> None:
        require("aiohttp", "station")
        if context is None and session is None:
            raise ValueError("StationServer needs a context, or a session to review")
        self.host, self.port = host, port
        self.limits = limits or TeleopLimits()
        self.teleop_period = 1.0 / teleop_rate_hz
        self.access = access or ConsoleAccess.create()
        self.bulk_window = bulk_window
        self.refused = 0
        """WebSocket requests refused (no or wrong token, foreign origin)."""
        self._context = context
        self._clients: dict[int, _Client] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self.session = session
        self.bridge: StationBridge | SessionBridge | None = None
        self._error: BaseException | None = None

    # -- lifecycle -------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start serving in a background thread; returns once listening."""
        missing = [f for f in VENDOR_FILES if not (STATIC_DIR / "vendor" / f).is_file()]
        if missing:
            log.warning("front-end dependencies missing (%s): run scripts/setup-frontend", ", ".join(missing))
        self._thread = threading.Thread(target=self._run, name="station", daemon=True)
        self._thread.start()
        self._ready.wait(20)
        if self._error is not None:
            raise self._error
        try:
            if self.session is not None:
                self.bridge = SessionBridge(self.session, self._emit_threadsafe)
            else:
                assert self._context is not None
                self.bridge = StationBridge(
                    self._context, self._emit_threadsafe, limits=self.limits, wanted_cameras=self._wanted_cameras
                )
        except BaseException:
            self.stop()
            raise

    @property
    def url(self) -> str:
        """The console's page, with the token the WebSocket asks for."""
        return f"http://{self.host}:{self.port}/?token={self.access.token}"

    @property
    def ws_url(self) -> str:
        """The WebSocket, with the token (for programs; the page builds it itself)."""
        return f"ws://{self.host}:{self.port}/ws?token={self.access.token}"

    def stop(self) -> None:
        if self.bridge is not None:
            self.bridge.close()
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        if self._thread is not None:
            self._thread.join(10)

    def __enter__(self) -> StationServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as err:  # surfaced to start()
            self._error = err
            self._ready.set()

    async def _serve(self) -> None:
        from aiohttp import web

        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_static("/static/", STATIC_DIR, show_index=False)
        runner = web.AppRunner(app)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port)
        await site.start()
        sockets = getattr(site._server, "sockets", None) or []
        if sockets:
            self.port = sockets[0].getsockname()[1]
        log.info("operator console at %s", self.url)
        self._ready.set()
        teleop = asyncio.create_task(self._teleop_loop())
        await self._stop.wait()
        teleop.cancel()
        for client in list(self._clients.values()):
            await client.socket.close()
        await runner.cleanup()

    # -- HTTP and WebSocket --------------------------------------------------------------------------------
    async def _index(self, request: Any) -> Any:
        from aiohttp import web

        return web.FileResponse(STATIC_DIR / "index.html")

    async def _websocket(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        refusal = self.access.refusal(
            token=request.query.get("token"), origin=request.headers.get("Origin"), host=request.host,
            secure=request.secure,
        )  # fmt: skip
        if refusal is not None:
            self.refused += 1
            log.warning("console WebSocket from %s refused: %s", request.remote, refusal)
            raise web.HTTPForbidden(text=refusal + "\n")
        socket = web.WebSocketResponse(heartbeat=5.0, max_msg_size=16 * 1024 * 1024)
        await socket.prepare(request)
        if request.query.get("role") == "link":
            return await self._link(socket)
        client = _Client(socket)
        limits = {"max_linear": self.limits.max_linear, "max_angular": self.limits.max_angular}
        agents = self.bridge.agent_names() if self.bridge else []
        client.queue({"type": "hello", "agents": agents, "limits": limits})
        if self.bridge is not None:
            for message in self.bridge.snapshot():
                client.queue(message)
        self._clients[id(socket)] = client
        sender = asyncio.create_task(self._sender(client))
        try:
            async for frame in socket:
                if frame.type == WSMsgType.TEXT:
                    await self._on_browser_message(client, frame.data)
                elif frame.type == WSMsgType.ERROR:
                    break
        finally:
            sender.cancel()
            self._clients.pop(id(socket), None)
            if self.bridge is not None:
                for agent in client.driving:
                    self.bridge.gate.release(agent)
                if client.driving:
                    self.bridge.tick_teleop(time.monotonic())
        return socket

    async def _link(self, socket: Any) -> Any:
        """The page's link indicator (a worker of its own, ``static/link.js``): pongs to its pings, nothing else."""
        from aiohttp import WSMsgType

        async for frame in socket:
            if frame.type != WSMsgType.TEXT:
                continue
            try:
                message = json.loads(frame.data)
                if message["type"] == "ping":
                    await socket.send_str(json.dumps({"type": "pong", "t": message.get("t")}))
            except (ValueError, KeyError, TypeError):
                log.warning("ignoring a malformed link message: %.80s", frame.data)
            except (ConnectionError, RuntimeError):
                break
        return socket

    async def _on_browser_message(self, client: _Client, text: str) -> None:
        try:
            message = json.loads(text)
            kind = message["type"]
        except (ValueError, KeyError, TypeError):
            log.warning("ignoring a malformed browser message: %.80s", text)
            return
        bridge = self.bridge
        if kind == "ping":
            client.queue({"type": "pong", "t": message.get("t")})
        elif kind == "ack":
            try:
                client.acked = max(client.acked, int(message.get("bytes", 0)))
            except (TypeError, ValueError):
                return
            client.wake.set()
        elif kind == "select":
            client.agent = str(message.get("agent") or "") or None
        elif kind == "camera":
            client.camera = "depth" if message.get("kind") == "depth" else "rgb"
        elif kind == "drive" and bridge is not None:
            agent = str(message.get("agent", ""))
            try:
                v, w = float(message.get("v", 0.0)), float(message.get("w", 0.0))
            except (TypeError, ValueError):
                return
            client.driving.add(agent)
            deadman = bool(message.get("deadman"))
            now = time.monotonic()
            bridge.gate.drive(agent, v, w, deadman, now)
            if not deadman:
                # A release goes out at once, not at the stream's next tick.
                bridge.tick_teleop(now)
        elif kind == "estop" and bridge is not None:
            agent, engage = str(message.get("agent", "")), bool(message.get("engage"))
            if engage:
                bridge.gate.release(agent)
            ok, detail = await asyncio.to_thread(bridge.estop, agent, engage)
            client.queue({"type": "estop", "agent": agent, "engaged": engage, "ok": ok, "message": detail})
        elif kind == "session_frame" and isinstance(bridge, SessionBridge):
            try:
                agent, t = str(message["agent"]), float(message["t"])
            except (KeyError, TypeError, ValueError):
                return
            client.queue(await asyncio.to_thread(bridge.frame, agent, t))
        elif (kind.startswith("finding_") or kind == "measure_pick") and bridge is not None:
            await self._on_finding_message(client, kind, message)

    # -- findings (fleetslam.station.findings) ---------------------------------------------------------------
    async def _on_finding_message(self, client: _Client, kind: str, message: dict[str, Any]) -> None:
        """A pick, a new finding, a change or a photo asked for: answered to this browser only (the fleet's
        ``findings`` reach every browser when the findings service publishes them)."""
        assert self.bridge is not None
        desk = self.bridge.findings
        try:
            if kind == "finding_pick":
                reply = await asyncio.to_thread(
                    desk.pick, str(message["agent"]), int(message["stamp"]), float(message["u"]), float(message["v"])
                )
            elif kind == "finding_create":
                reply = await asyncio.to_thread(
                    desk.create, str(message["pick"]), str(message.get("title", "")),
                    str(message.get("severity", "")), str(message.get("note", "")),
                )  # fmt: skip
            elif kind == "finding_update":
                reply = await asyncio.to_thread(desk.update, str(message["id"]), message)
            elif kind == "finding_photo":
                reply = desk.photo(str(message["id"]))
            elif kind == "measure_pick":
                reply = await asyncio.to_thread(
                    desk.locate, str(message["agent"]), int(message["stamp"]), float(message["u"]), float(message["v"])
                )
            else:
                return
        except (KeyError, TypeError, ValueError) as err:
            log.warning("ignoring a malformed %s message: %s", kind, err)
            return
        client.queue(reply)

    async def _teleop_loop(self) -> None:
        next_tick = time.monotonic()
        while True:
            if self.bridge is not None:
                self.bridge.tick_teleop(time.monotonic())
            next_tick += self.teleop_period
            await asyncio.sleep(max(0.0, next_tick - time.monotonic()))

    # -- bridge → browsers ---------------------------------------------------------------------------------
    def _wanted_cameras(self) -> set[tuple[str, str]]:
        return {(c.agent, c.camera) for c in list(self._clients.values()) if c.agent}

    def _emit_threadsafe(self, message: dict[str, Any], agent_filter: str | None) -> None:
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        loop.call_soon_threadsafe(self._broadcast, message, agent_filter)

    def _broadcast(self, message: dict[str, Any], agent_filter: str | None) -> None:
        for client in list(self._clients.values()):
            if agent_filter is not None and (client.agent != agent_filter or client.camera != message.get("kind")):
                continue
            if not client.socket.closed:
                client.queue(message)

    async def _sender(self, client: _Client) -> None:
        """Sends a browser's messages: control messages at once, bulk ones while the page keeps up (acknowledges
        them) — so a pong waits behind at most ``bulk_window`` of bulk data, and a busy page gets the newest
        image, pose and map instead of a backlog."""
        socket = client.socket
        try:
            while not socket.closed:
                await client.wake.wait()
                client.wake.clear()
                while client.control or (client.bulk and client.sent - client.acked < self.bulk_window):
                    if client.control:
                        await socket.send_str(client.control.popleft())
                        continue
                    item = client.bulk.pop(next(iter(client.bulk)))
                    if isinstance(item, VoxelUpdate):
                        data = item.encode()
                        client.sent += len(data)
                        await socket.send_bytes(data)
                    else:
                        text = json.dumps(item)
                        client.sent += len(text)
                        await socket.send_str(text)
        except (ConnectionError, RuntimeError) as err:
            log.debug("browser went away: %s", err)
