"""Loopback CAN hub for machines without SocketCAN.

python-can-remote serves one ``virtual`` channel over WebSocket; each client
(``can.Bus(interface="remote", channel=hub.url)``) gets its own virtual bus on that channel
inside the server, so every frame a client sends reaches every other client. Bound to
127.0.0.1 only (the package's default is 0.0.0.0), on a free port unless one is given.

A client that goes away abruptly (killed, its connection reset) is a debug log line, not
socketserver's traceback on stderr; ``close()`` ends every client's connection and waits for
its thread, so nothing of the hub outlives it.
"""
from __future__ import annotations

import logging
import socket
import sys
import threading
import uuid

from can_remote.server import RemoteServer

from protocol.can.busconfig import BusConfig

log = logging.getLogger(__name__)

HOST = "127.0.0.1"
CLOSE_S = 5.0
"""How long ``close()`` waits for a client's thread (its relay ends within 0.5 s)."""


class _Server(RemoteServer):
    """python-can-remote's server, knowing its clients' connections and threads."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003
        self._clients: dict[socket.socket, threading.Thread] = {}
        self._clients_lock = threading.Lock()
        super().__init__(*args, **kwargs)

    def process_request_thread(self, request: socket.socket, client_address) -> None:  # noqa: ANN001
        with self._clients_lock:
            self._clients[request] = threading.current_thread()
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._clients_lock:
                self._clients.pop(request, None)

    def handle_error(self, request: socket.socket, client_address) -> None:  # noqa: ANN001
        log.debug("CAN hub client %s:%s gone: %r", *client_address[:2], sys.exc_info()[1])

    def end_clients(self, timeout_s: float) -> None:
        """Shut every client's connection (its relay then ends) and wait for its thread."""
        with self._clients_lock:
            clients = dict(self._clients)
        for request in clients:
            try:
                request.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass  # already gone
        for thread in clients.values():
            thread.join(timeout_s)


class LoopbackHub:
    """A running hub. Use as a context manager or call ``close()``."""

    def __init__(self, port: int = 0, channel: str | None = None) -> None:
        self.channel = channel or f"ersac-hub-{uuid.uuid4().hex[:8]}"
        self._server = _Server(HOST, port, bustype="virtual", channel=self.channel)
        self.port: int = self._server.server_port
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name=f"can-hub:{self.port}", daemon=True)
        self._thread.start()
        self._closed = False
        log.info("loopback CAN hub on %s", self.url)

    @property
    def url(self) -> str:
        return f"ws://{HOST}:{self.port}/"

    @property
    def bus_config(self) -> BusConfig:
        """What a client passes to ``protocol.can.open_bus``."""
        return BusConfig("remote", self.url)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=2.0)
        self._server.end_clients(CLOSE_S)

    def __enter__(self) -> "LoopbackHub":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
