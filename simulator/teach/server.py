"""The page and its WebSocket, served with the ``websockets`` library (no HTTP code of ours).

``GET /`` (and ``/teach.js``, ``/teach.css``) are the page's files, answered from
``process_request``; ``/ws`` is the WebSocket: on connect the page gets ``config`` (key map,
action names and ranges, field geometry, start locations, clock, who drives in autonomous
mode), then ``state`` at :data:`STATE_HZ` (the newest tick: perception, commands, prediction,
expert, counts, the camera image at :data:`IMAGE_HZ`, the top view's truth). A connection that
says ``hello`` with ``ticks`` also gets every tick (the scripted teacher, which answers each
one in lockstep). Every frame a page sends goes through :class:`~simulator.teach.channel.Guard`:
refused frames are counted by reason, answered at most once a second per reason, and change
nothing. Only pages served from this address (or clients sending no ``Origin``, such as the
scripted teacher) may open the WebSocket.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections import Counter
from collections.abc import Callable
from http import HTTPStatus
from importlib import resources
from typing import Any

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from simulator.teach.channel import Guard, PageInput, Refused

__all__ = ["IMAGE_HZ", "STATE_HZ", "PageServer"]

log = logging.getLogger("roger.teach")
#: How often every page gets the newest state, and the camera image.
STATE_HZ = 15.0
IMAGE_HZ = 10.0
_FILES = {"/": ("index.html", "text/html; charset=utf-8"),
          "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/teach.js": ("teach.js", "text/javascript; charset=utf-8"),
          "/teach.css": ("teach.css", "text/css; charset=utf-8")}


def _static(name: str) -> str:
    return (resources.files("simulator.teach") / "static" / name).read_text("utf-8")


class PageServer:
    """The page's server for one :class:`~simulator.teach.loop.TeachLoop`.

    ``handle(req)`` carries out an accepted input that is not a command (mode, reset, ball,
    record, checkpoint) and returns a short answer for the page; ``snapshot()`` is the loop's
    newest state; ``image()`` the newest camera JPEG (base64) or ``""``.
    """

    def __init__(self, host: str, port: int, config: dict[str, Any], *,
                 submit: Callable[[PageInput], None], handle: Callable[[PageInput], str],
                 snapshot: Callable[[], dict[str, Any]], image: Callable[[], str],
                 refused: Counter[str], limits: dict[str, Any] | None = None) -> None:
        self.host, self.port = host, port
        self.config = config
        self.submit, self.handle, self.snapshot, self.image = submit, handle, snapshot, image
        self.refused = refused
        self.limits = limits or {}
        self.pages: set[ServerConnection] = set()
        self.tick_subscribers: dict[ServerConnection, asyncio.Queue[str]] = {}
        self.sent_states = 0
        self.allowed: set[str] = set()
        self._aio: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None

    # -- HTTP ----------------------------------------------------------------------------------

    def _http(self, connection: ServerConnection, request: Request) -> Response | None:
        path = request.path.split("?", 1)[0]
        if path == "/ws":
            origin = request.headers.get("Origin")
            if origin is not None and origin not in self.allowed:
                self.refused["origin"] += 1
                return connection.respond(HTTPStatus.FORBIDDEN, "origin not allowed\n")
            return None  # the WebSocket handshake goes on
        if path == "/favicon.ico":
            return connection.respond(HTTPStatus.NO_CONTENT, "")
        if path not in _FILES:
            return connection.respond(HTTPStatus.NOT_FOUND, "not found\n")
        name, content_type = _FILES[path]
        resp = connection.respond(HTTPStatus.OK, _static(name))
        del resp.headers["Content-Type"]
        resp.headers["Content-Type"] = content_type
        resp.headers["Cache-Control"] = "no-store"
        return resp

    # -- WebSocket -----------------------------------------------------------------------------

    async def _handler(self, ws: ServerConnection) -> None:
        guard = Guard(self.refused)
        answered: dict[str, float] = {}
        self.pages.add(ws)
        try:
            await ws.send(json.dumps({"type": "config", **self.config}))
            async for frame in ws:
                try:
                    req = guard.check(frame, **self.limits)
                except Refused as exc:
                    await self._refuse(ws, exc, answered)
                    continue
                await self._dispatch(ws, req)
        except ConnectionClosed:
            pass
        finally:
            self.pages.discard(ws)
            self.tick_subscribers.pop(ws, None)

    async def _refuse(self, ws: ServerConnection, exc: Refused, answered: dict[str, float]
                      ) -> None:
        now = time.monotonic()
        if self.refused[exc.reason] == 1:
            log.warning("refused a page input (%s); further ones are only counted", exc)
        if now - answered.get(exc.reason, -1e9) >= 1.0:
            answered[exc.reason] = now
            await ws.send(json.dumps({"type": "refused", "reason": exc.reason,
                                      "detail": exc.detail, "counts": dict(self.refused)}))

    async def _dispatch(self, ws: ServerConnection, req: PageInput) -> None:
        if req.type == "command":
            self.submit(req)
            return
        if req.type == "hello":
            if req.ticks and ws not in self.tick_subscribers:
                queue: asyncio.Queue[str] = asyncio.Queue()
                self.tick_subscribers[ws] = queue
                asyncio.create_task(self._forward_ticks(ws, queue))
            return
        text = await asyncio.to_thread(self.handle, req)
        await ws.send(json.dumps({"type": "ack", "op": req.type, "text": text}))

    async def _forward_ticks(self, ws: ServerConnection, queue: asyncio.Queue[str]) -> None:
        with contextlib.suppress(ConnectionClosed):
            while ws in self.tick_subscribers:
                await ws.send(await queue.get())

    def publish_tick(self, msg: dict[str, Any]) -> None:
        """Every tick, from the loop's thread: to the connections that said ``hello``."""
        if not self.tick_subscribers or self._aio is None:
            return
        text = json.dumps(msg)
        for queue in list(self.tick_subscribers.values()):
            self._aio.call_soon_threadsafe(queue.put_nowait, text)

    async def _broadcast(self) -> None:
        last_tick, last_image = -1, 0.0
        while True:
            await asyncio.sleep(1.0 / STATE_HZ)
            snap = self.snapshot()
            if not self.pages or not snap or snap.get("tick") == last_tick:
                continue
            last_tick = snap["tick"]
            msg = {"type": "state", **snap, "refused": dict(self.refused),
                   "pages": len(self.pages)}
            now = time.monotonic()
            if now - last_image >= 1.0 / IMAGE_HZ - 1e-3:
                last_image = now
                msg["image"] = self.image()
            text = json.dumps(msg)
            for ws in list(self.pages):
                with contextlib.suppress(ConnectionClosed):
                    await ws.send(text)
            self.sent_states += 1

    async def serve(self, ready: Callable[[str], None], stop: asyncio.Event) -> None:
        """Serve until ``stop`` is set; ``ready(url)`` once listening."""
        self._aio = asyncio.get_running_loop()
        async with serve(self._handler, self.host, self.port, process_request=self._http,
                         max_size=2**16, ping_interval=None) as server:
            self._server = server
            self.port = int(server.sockets[0].getsockname()[1])
            self.allowed = {f"http://{h}:{self.port}" for h in ("127.0.0.1", "localhost",
                                                                 self.host)}
            broadcast = asyncio.create_task(self._broadcast())
            ready(f"http://{self.host}:{self.port}/")
            await stop.wait()
            broadcast.cancel()
