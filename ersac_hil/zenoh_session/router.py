"""The embedded router: a Zenoh router session inside this Python process (``ersac-hil router``,
tests, benches)."""
from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any, Self

import zenoh

from .config import json_at, make_config
from .endpoints import free_tcp_port, loopback_endpoint, split_endpoint
from .errors import ZenohConfigError, ZenohSessionError
from .session import open_session

__all__ = ["EmbeddedRouter"]


class EmbeddedRouter:
    """A Zenoh router inside this Python process.

    Args:
        port: TCP port on 127.0.0.1; ``None`` picks a free one (retried if another process
            grabs it).
        extra: extra config values (see :func:`make_config`), e.g. authentication.
        config: a complete router config instead (``resolve_config(..., mode="router")``:
            TLS listeners, access control); ``port`` and ``extra`` must not be given.
        insecure: passed to :func:`open_session` with ``config``.

    Use as a context manager, or ``start()`` / ``close()``; ``wait()`` blocks (CLI).
    """

    def __init__(self, port: int | None = None, *, extra: Mapping[str, Any] | None = None,
                 config: zenoh.Config | None = None, insecure: bool = False) -> None:
        if port is not None:
            loopback_endpoint(port)
        if config is not None and (port is not None or extra):
            raise ZenohConfigError("give the router a config, or a port and extra values, not both")
        self._requested = port
        self._extra = dict(extra or {})
        self._config = config
        self._insecure = insecure
        self._endpoint: str | None = None
        self._port: int | None = None
        self._session: zenoh.Session | None = None
        self._stopped = threading.Event()

    def start(self, attempts: int = 5) -> Self:
        """Open the router session. Idempotent.

        Raises:
            ZenohSessionError: the port is in use (explicit port) or every attempt failed.
        """
        if self._session is not None:
            return self
        if self._config is not None:
            self._session = open_session(self._config, insecure=self._insecure)
            self._endpoint = json_at(self._config, "listen/endpoints")[0]
            self._port = split_endpoint(self._endpoint)[2]
            self._stopped.clear()
            return self
        tries = 1 if self._requested is not None else max(1, attempts)
        for attempt in range(tries):
            port = self._requested if self._requested is not None else free_tcp_port()
            config = make_config("router", listen=[loopback_endpoint(port)], extra=self._extra)
            try:
                self._session = open_session(config)
            except ZenohSessionError:
                if attempt + 1 == tries:
                    raise
                continue
            self._port = port
            self._endpoint = loopback_endpoint(port)
            self._stopped.clear()
            return self
        raise AssertionError("unreachable")  # pragma: no cover

    @property
    def running(self) -> bool:
        """Whether the router session is open."""
        return self._session is not None and not self._session.is_closed()

    @property
    def port(self) -> int:
        """The TCP port listened on (after :meth:`start`)."""
        if self._port is None:
            raise ZenohSessionError("router not started")
        return self._port

    @property
    def endpoint(self) -> str:
        """``tcp/127.0.0.1:<port>`` (with a config: its first listen endpoint)."""
        if self._endpoint is None:
            raise ZenohSessionError("router not started")
        return self._endpoint

    @property
    def session(self) -> zenoh.Session:
        """The router's own session (it can declare entities like any other)."""
        if self._session is None:
            raise ZenohSessionError("router not started")
        return self._session

    def client_config(self, mode: str = "client", **kwargs: Any) -> zenoh.Config:
        """A config connecting to this router (``mode`` client or peer; kwargs to make_config)."""
        return make_config(mode, connect=[self.endpoint], **kwargs)

    def open_client(self, mode: str = "client", **kwargs: Any) -> zenoh.Session:
        """Open a session connected to this router. The caller closes it."""
        return open_session(self.client_config(mode, **kwargs))

    def wait(self, stop: threading.Event | None = None, poll_s: float = 0.2) -> None:
        """Block until :meth:`close` is called, ``stop`` is set or Ctrl-C; then close."""
        try:
            while not self._stopped.is_set() and not (stop is not None and stop.is_set()):
                self._stopped.wait(poll_s)
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        """Close the router session. Idempotent."""
        session, self._session = self._session, None
        self._stopped.set()
        if session is not None:
            session.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = f"on {self.endpoint}" if self._endpoint is not None and self.running else "stopped"
        return f"EmbeddedRouter({state})"
