"""The live page's web server (aiohttp): the page, and frames over a WebSocket.

- It serves exactly two paths, ``/`` (the page, ``static/index.html``) and
  ``/ws`` (the WebSocket), compared with the request's raw path: anything
  else (``/../``, ``//etc/passwd``, ``/%2e%2e/``, other files) is 404.
- The WebSocket accepts only the page's own origin (``http://HOST:PORT``,
  and ``localhost`` for a loopback host); any other ``Origin``, or none, is 403.
- One viewer at a time: a second connection gets a ``refused`` message and
  is closed; the first keeps its stream.
- Each text message is checked by :func:`denoise.live.session.parse_message`;
  a bad one gets ``{"type": "error", "message": ...}`` back and the stream goes on.
"""
from __future__ import annotations

import asyncio
import logging
import signal
import socket
import threading
from pathlib import Path

from aiohttp import WSMsgType, web

from core.entry import Interrupted
from core.errors import UsageError

from .methods import METHOD_NAMES, describe
from .session import SIZES, MessageError, Session, parse_message

PAGE = Path(__file__).parent / "static" / "index.html"
#: the raw request paths served; every other is 404
PATHS = ("/", "/ws")
#: aiohttp's own frame limit, above ours so that a long message gets our error, not a closed socket
SOCKET_LIMIT = 1 << 20
#: seconds :meth:`LiveServer.publish` waits at most for the event loop to hand a frame to the socket
SEND_WAIT_S = 0.05
#: seconds between the server's pings; a viewer that has not answered one within half of it is closed, so a
#: client that connects and goes silent (never reads, never answers) does not hold the one viewer's place
HEARTBEAT_S = 15.0
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def check_port(host: str, port: int) -> None:
    """Raises UsageError (one line) where ``host:port`` cannot be listened on,
    before the scene is loaded (aiohttp binds it again once ready)."""
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as aiohttp binds
            probe.bind((host, port))
    except OSError as error:
        raise UsageError(port_message(host, port, error)) from None


def port_message(host: str, port: int, error: OSError) -> str:
    return (f"cannot listen on {host}:{port}: {error.strerror or error}"
            + (" (another server uses that port; choose another with --port)" if error.errno == 98 else ""))


def allowed_origins(host: str, port: int) -> set[str]:
    """The origins of the page as a browser sees it when it opens the printed address."""
    names = {host} | (set(LOOPBACK) - {"::1"} if host in LOOPBACK else set())
    return {f"http://{name}:{port}" for name in names} | ({f"http://[::1]:{port}"} if host in LOOPBACK else set())


class LiveServer:
    """The app and its one viewer; frames come from :meth:`publish` (any thread)."""

    def __init__(self, session: Session, host: str, port: int, hello: dict):
        self.session, self.host, self.port, self.hello = session, host, port, hello
        self.viewer: web.WebSocketResponse | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.on_shown = None  # frame number -> None, called when the page acknowledges a frame
        self.failed = asyncio.Event()  # set to stop: the frame loop failed, or a signal came
        self.signal: int | None = None
        self.app = web.Application(middlewares=[self.only_own_paths])
        self.app.router.add_get("/", self.page)
        self.app.router.add_get("/ws", self.socket)

    @web.middleware
    async def only_own_paths(self, request: web.Request, handler):
        if request.raw_path.split("?", 1)[0] not in PATHS:
            raise web.HTTPNotFound(text="not found\n")
        return await handler(request)

    async def page(self, request: web.Request) -> web.StreamResponse:
        return web.Response(body=PAGE.read_bytes(), content_type="text/html", charset="utf-8",
                            headers={"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff"})

    def state(self) -> dict:
        view = self.session.view()
        return {"type": "state", "method": view.method, "paused": self.session.paused,
                "size": "{}x{}".format(*view.size), "sliders": describe(view.method, view.size[0], dict(view.values))}

    async def socket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin not in allowed_origins(self.host, self.port):
            raise web.HTTPForbidden(text=f"WebSocket from origin {origin!r} refused\n")
        # no permessage-deflate: frames are JPEGs already, and aiohttp compresses a message over
        # 16 KiB in an executor thread, a hop (and the GIL) between the frame loop and the socket
        ws = web.WebSocketResponse(max_msg_size=SOCKET_LIMIT, heartbeat=HEARTBEAT_S, compress=False)
        await ws.prepare(request)
        if self.viewer is not None and not self.viewer.closed:
            await ws.send_json({"type": "refused", "message": "another viewer is already connected; close that "
                                                              "page first (one viewer at a time)"})
            await ws.close(code=4001, message=b"one viewer at a time")
            return ws
        self.viewer = ws
        self.session.connect(True)
        width, height = self.session.view().size  # the size now: an earlier viewer may have changed it
        await ws.send_json(dict(self.hello, type="hello", width=width, height=height, methods=list(METHOD_NAMES)))
        await ws.send_json(self.state())
        try:
            async for message in ws:
                if message.type != WSMsgType.TEXT:
                    if message.type == WSMsgType.BINARY:
                        await ws.send_json({"type": "error", "message": "expected a text message (JSON)"})
                    continue
                await self.handle(ws, message.data)
        finally:
            if self.viewer is ws:
                self.viewer = None
                self.session.connect(False)
        return ws

    async def handle(self, ws: web.WebSocketResponse, text: str) -> None:
        try:
            message = parse_message(text, self.session.view().method)
            self.session.apply(message)
        except MessageError as error:
            await ws.send_json({"type": "error", "message": str(error)})
            return
        if message["type"] == "ack":
            if self.on_shown is not None:
                self.on_shown(message["frame"])
        elif message["type"] in ("method", "param", "pause", "reset_view", "size"):
            await ws.send_json(self.state())

    def stop_on(self, signum: int) -> None:
        """SIGINT or SIGTERM: stop serving; :meth:`serve` then raises ``Interrupted``."""
        self.signal = signum
        self.failed.set()

    def publish(self, data: bytes | None) -> None:
        """Sends a frame to the viewer (from the frame loop's thread), returning once it is
        handed to the socket (or after :data:`SEND_WAIT_S`); None: the loop failed."""
        if self.loop is None or self.signal is not None:
            return
        written = threading.Event()
        try:
            self.loop.call_soon_threadsafe(self._send, data, written)
        except RuntimeError:  # the event loop closed while this frame was made: the server is stopping
            return
        if data is not None:  # the frame goes out before the caller traces its next one (both need the GIL)
            written.wait(SEND_WAIT_S)

    def _send(self, data: bytes | None, written: threading.Event) -> None:
        if data is None:
            self.failed.set()
            return
        viewer = self.viewer
        if viewer is not None and not viewer.closed:
            asyncio.ensure_future(self._send_bytes(viewer, data))
        # after the send's first step, which writes the frame to the socket (what the socket does
        # not take at once, asyncio sends when it can): not after a drain, which waits for the page
        self.loop.call_soon(written.set)

    @staticmethod
    async def _send_bytes(viewer: web.WebSocketResponse, data: bytes) -> None:
        try:
            await viewer.send_bytes(data)
        except (ConnectionError, RuntimeError):  # the page went away meanwhile
            pass

    async def serve(self, ready) -> None:
        """Listens until cancelled (or the frame loop fails); ``ready(url)`` once listening."""
        self.loop = asyncio.get_running_loop()
        # a malformed request gets its 400 from aiohttp; its traceback would break the one-line log
        logging.getLogger("aiohttp.server").setLevel(logging.CRITICAL)
        runner = web.AppRunner(self.app, handle_signals=False, access_log=None)
        await runner.setup()
        try:
            await web.TCPSite(runner, self.host, self.port).start()
        except OSError as error:
            await runner.cleanup()
            raise UsageError(port_message(self.host, self.port, error)) from None
        self.port = runner.addresses[0][1]  # the one bound (--port 0 picks a free one)
        # signals through the loop (its wakeup fd): delivered to a render thread, a plain
        # handler would wait for the main thread to leave select()
        for signum in (signal.SIGINT, signal.SIGTERM):
            self.loop.add_signal_handler(signum, self.stop_on, signum)
        host = f"[{self.host}]" if ":" in self.host else self.host
        ready(f"http://{host}:{self.port}/")
        # no graceful shutdown or closing handshake: both wait for the viewer (seconds); the
        # process ends, and the page sees its connection drop
        await self.failed.wait()
        if self.signal is not None:
            raise Interrupted(self.signal)


def hello_message(scene: str, width: int, height: int, variant: str, frozen: bool, light: bool) -> dict:
    return {"scene": scene, "width": width, "height": height, "variant": variant, "frozen": frozen,
            "light": light, "sizes": list(SIZES)}

