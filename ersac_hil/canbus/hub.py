"""Loopback CAN hub for machines without SocketCAN.

python-can-remote serves one ``virtual`` channel over WebSocket; each client
(``can.Bus(interface="remote", channel=hub.url)``) gets its own virtual bus on that channel
inside the server, so every frame a client sends reaches every other client. Bound to
127.0.0.1 only (the package's default is 0.0.0.0), on a free port unless one is given.
"""
from __future__ import annotations

import logging
import threading
import uuid

from can_remote.server import RemoteServer

from protocol.can.busconfig import BusConfig

log = logging.getLogger(__name__)

HOST = "127.0.0.1"


class LoopbackHub:
    """A running hub. Use as a context manager or call ``close()``."""

    def __init__(self, port: int = 0, channel: str | None = None) -> None:
        self.channel = channel or f"ersac-hub-{uuid.uuid4().hex[:8]}"
        self._server = RemoteServer(HOST, port, bustype="virtual", channel=self.channel)
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

    def __enter__(self) -> "LoopbackHub":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
