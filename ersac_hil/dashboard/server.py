"""The dashboard's web server: one page, a JSON API and server-sent events (Starlette + uvicorn).

Routes:

======================  =======================================================================
``GET /``               the page (read-only: without the controls)
``GET /static/...``     ``app.js``, ``style.css`` (this package), ``plotly.min.js`` (the Plotly
                        Python package's bundled copy: no CDN)
``GET /api/state``      a fresh ``learner/state`` reply: the JSON ``ersac-hil state --json`` prints
``GET /api/snapshot``   everything the page shows (``DashboardModel.snapshot``)
``GET /api/events``     ``text/event-stream``: a ``snapshot`` event, then every model event
``POST /api/kappa``     see :mod:`ersac_hil.dashboard.api`; 403 when read-only
``POST /api/weights``
``POST /api/select``
``POST /api/adopt``
======================  =======================================================================

Bound to 127.0.0.1 by default; on a loopback address, requests whose ``Host`` is not a
loopback name are refused (DNS rebinding). Control endpoints take ``application/json`` only, so
a foreign web page cannot post to them without a CORS preflight, which this server never grants.
"""
from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import socket
import threading
from collections.abc import AsyncIterator, Callable
from importlib import resources
from pathlib import Path
from typing import Any

import anyio
import plotly
import uvicorn
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from . import api
from .bridge import Bridge
from .model import Event

__all__ = ["EventHub", "build_app", "WebServer", "is_loopback", "PLOTLY_JS", "STATIC", "PAGE_FILES"]

log = logging.getLogger(__name__)

PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
#: The page's own files (package data: index.html, app.js, style.css).
STATIC = resources.files("ersac_hil.dashboard") / "static"
PAGE_FILES = ("index.html", "app.js", "style.css")
_KEEPALIVE_S = 15.0
_QUEUE_EVENTS = 10_000


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _sse(kind: str, data: dict[str, Any]) -> bytes:
    return f"event: {kind}\nid: {data.get('seq', 0)}\ndata: {json.dumps(data, allow_nan=False)}\n\n".encode()


class EventHub:
    """Fans model events out to every open event stream (asyncio side; fed from any thread).

    Args:
        snapshot: returns the model's snapshot (with its ``seq``), thread-safe.
    """

    def __init__(self, snapshot: Callable[[], dict[str, Any]]) -> None:
        self._snapshot = snapshot
        self._queues: set[asyncio.Queue[Event | None]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed = False

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def publish(self, event: Event) -> None:
        """Thread-safe; events published before the server's loop runs are only in the model."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._deliver, event)
            except RuntimeError:  # loop closed in between
                pass

    def _deliver(self, event: Event | None) -> None:
        for q in list(self._queues):
            try:
                q.put_nowait(event)
            except asyncio.QueueFull:  # a client that does not read: drop it, it reconnects
                self._queues.discard(q)

    def close(self) -> None:
        """End every stream (the server can then shut down). Thread-safe."""
        self._closed = True
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._deliver, None)
            except RuntimeError:
                pass

    async def stream(self) -> AsyncIterator[bytes]:
        queue: asyncio.Queue[Event | None] = asyncio.Queue(_QUEUE_EVENTS)
        self._queues.add(queue)
        try:
            snapshot = self._snapshot()
            seen = snapshot["seq"]
            yield _sse("snapshot", snapshot)
            while not self._closed:
                try:
                    event = await asyncio.wait_for(queue.get(), _KEEPALIVE_S)
                except TimeoutError:
                    yield b": keepalive\n\n"
                    continue
                if event is None:
                    return
                kind, data = event
                if data["seq"] <= seen:
                    continue  # already in the snapshot
                yield _sse(kind, data)
        finally:
            self._queues.discard(queue)


def _page(read_only: bool) -> str:
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    if read_only:
        start, end = html.index("<!-- controls -->"), html.index("<!-- /controls -->")
        html = html[:start] + html[end:]
    return html


def build_app(bridge: Bridge, hub: EventHub, *, read_only: bool, loopback: bool) -> Starlette:
    """The Starlette application around ``bridge``."""
    page = _page(read_only)

    async def index(_request: Request) -> Response:
        return HTMLResponse(page, headers={"Cache-Control": "no-store"})

    async def static(request: Request) -> Response:
        name = request.path_params["name"]
        if name == "plotly.min.js":
            return FileResponse(PLOTLY_JS, media_type="text/javascript")
        if name not in PAGE_FILES[1:]:
            return JSONResponse({"error": {"code": "not_found", "reason": name}}, 404)
        media = "text/javascript" if name.endswith(".js") else "text/css"
        return Response((STATIC / name).read_bytes(), media_type=media,
                        headers={"Cache-Control": "no-cache"})

    def refused(exc: Exception) -> JSONResponse:
        error = api.error_from_exception(exc)
        return JSONResponse(error.body(), error.status)

    async def state(_request: Request) -> Response:
        try:
            reply = await anyio.to_thread.run_sync(bridge.state)
        except Exception as exc:  # noqa: BLE001 - mapped or re-raised
            return refused(exc)
        return Response(reply.to_json(), media_type="application/json")

    async def snapshot(_request: Request) -> Response:
        return JSONResponse(bridge.snapshot())

    async def events(_request: Request) -> Response:
        return StreamingResponse(hub.stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    def control(action: Callable[[dict[str, Any]], Any]):  # noqa: ANN202
        async def endpoint(request: Request) -> Response:
            if read_only:
                return refused(api.FORBIDDEN)
            try:
                body = api.parse_body(await request.body(), request.headers.get("content-type"))
                reply = await anyio.to_thread.run_sync(action, body)
            except Exception as exc:  # noqa: BLE001 - mapped or re-raised
                return refused(exc)
            return Response(reply.to_json(), media_type="application/json")
        return endpoint

    def set_kappa(body: dict[str, Any]) -> Any:
        return bridge.set_kappa(api.kappa_command(body))

    def set_weights(body: dict[str, Any]) -> Any:
        return bridge.set_weights(api.weights_command(body, bridge.state()))

    def select(adopt: bool) -> Callable[[dict[str, Any]], Any]:
        return lambda body: bridge.select(api.select_query(body, bridge.state(), adopt))

    routes = [
        Route("/", index),
        Route("/static/{name}", static),
        Route("/api/state", state),
        Route("/api/snapshot", snapshot),
        Route("/api/events", events),
        Route("/api/kappa", control(set_kappa), methods=["POST"]),
        Route("/api/weights", control(set_weights), methods=["POST"]),
        Route("/api/select", control(select(False)), methods=["POST"]),
        Route("/api/adopt", control(select(True)), methods=["POST"]),
    ]
    middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=["127.0.0.1", "localhost", "[::1]"])] \
        if loopback else []
    return Starlette(routes=routes, middleware=middleware)


class WebServer:
    """uvicorn serving ``app`` on an already bound socket, in a thread of its own.

    Args:
        app: the ASGI app. hub: its event hub (bound to the server's loop, closed on stop).
        host, port: where to listen (port 0: a free one; :attr:`port` tells which).

    Raises:
        OSError: the address cannot be bound (port in use, no such address).
    """

    def __init__(self, app: Starlette, hub: EventHub, host: str, port: int) -> None:
        self.hub = hub
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
            self._sock.listen(128)
        except OSError:
            self._sock.close()
            raise
        self.host = host
        self.port = self._sock.getsockname()[1]
        config = uvicorn.Config(app, lifespan="off", log_level="warning", access_log=False,
                                timeout_graceful_shutdown=2)
        self._server = uvicorn.Server(config)
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="dashboard-http", daemon=True)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self.hub.bind(loop)
        loop.call_soon(self._ready.set)
        try:
            loop.run_until_complete(self._server.serve(sockets=[self._sock]))
        finally:
            loop.close()

    def start(self, timeout_s: float = 10.0) -> WebServer:
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"the web server did not start within {timeout_s:g} s")
        return self

    def stop(self) -> None:
        self.hub.close()
        self._server.should_exit = True
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)
        self._sock.close()
