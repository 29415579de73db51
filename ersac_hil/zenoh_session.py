"""Loopback-only Zenoh sessions: config builder, session opener, embedded router.

Every session this project opens goes through :func:`make_config` and :func:`open_session`:

* explicit endpoints only: ``listen/endpoints`` is always set (Zenoh's default listener is
  ``tcp/[::]:0`` on every interface) and every endpoint must be ``tcp/<IPv4 loopback>:PORT``;
* multicast scouting off, gossip scouting off unless asked for, no scouting delay (the
  default 500 ms delay only waits for multicast replies we never send);
* :func:`open_session` refuses any config that breaks these rules, including a bare
  ``zenoh.Config()``.

Typical use::

    with EmbeddedRouter() as router:                       # router on 127.0.0.1:<free port>
        with session_scope(router.client_config()) as s:   # closed on exit, even on error
            s.put("ersac/ubot1/learner/kappa", KappaCommand(0.5).to_json())

A router for other processes (CLI): ``EmbeddedRouter(port=7447).start().wait()``.
"""

from __future__ import annotations

import ipaddress
import json
import re
import socket
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any, Self

import zenoh

__all__ = [
    "MODES",
    "ZenohConfigError",
    "EndpointError",
    "ZenohSessionError",
    "loopback_endpoint",
    "check_endpoint",
    "free_tcp_port",
    "make_config",
    "check_config",
    "open_session",
    "session_scope",
    "wait_for_match",
    "EmbeddedRouter",
]

#: Zenoh session modes.
MODES: tuple[str, ...] = ("router", "peer", "client")
_ENDPOINT = re.compile(r"tcp/(?P<host>[^/:?#\[\]]+):(?P<port>[0-9]{1,5})")
#: Config sections only make_config may set.
_PROTECTED = ("mode", "listen", "connect", "scouting")


class ZenohConfigError(ValueError):
    """A session configuration that this project refuses to use."""


class EndpointError(ZenohConfigError):
    """An endpoint that is not ``tcp/<IPv4 loopback>:PORT``."""


class ZenohSessionError(RuntimeError):
    """Zenoh could not open a session (port in use, no router to connect to...)."""


def loopback_endpoint(port: int, host: str = "127.0.0.1") -> str:
    """``tcp/127.0.0.1:<port>``, checked."""
    return check_endpoint(f"tcp/{host}:{port}")


def check_endpoint(endpoint: Any) -> str:
    """Return ``endpoint`` if it is ``tcp/<IPv4 loopback>:<1..65535>``.

    Raises:
        EndpointError: anything else (other protocol, IPv6, host name, wildcard address,
            port 0, endpoint metadata or configuration after ``?``/``#``).
    """
    if not isinstance(endpoint, str):
        raise EndpointError(f"endpoint must be a string, got {type(endpoint).__name__}")
    match = _ENDPOINT.fullmatch(endpoint)
    if match is None:
        raise EndpointError(
            f"endpoint {endpoint[:120]!r} is not of the form tcp/127.0.0.1:PORT "
            "(only TCP over IPv4 loopback, no metadata)"
        )
    host, port = match["host"], int(match["port"])
    try:
        address = ipaddress.IPv4Address(host)
    except ValueError:
        raise EndpointError(
            f"endpoint {endpoint!r}: host {host!r} is not an IPv4 address (names such as "
            "'localhost' may resolve to non-loopback or IPv6 addresses)"
        ) from None
    if not address.is_loopback:
        raise EndpointError(f"endpoint {endpoint!r}: {host} is not a loopback address")
    if not 1 <= port <= 65535:
        raise EndpointError(f"endpoint {endpoint!r}: port must be in 1..65535")
    return endpoint


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago (bind to port 0, then release).

    Another process may take it before you bind it: :class:`EmbeddedRouter` retries.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def make_config(
    mode: str = "client",
    *,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    connect_timeout_s: float | None = None,
    gossip: bool = False,
    extra: Mapping[str, Any] | None = None,
) -> zenoh.Config:
    """Build a loopback-only :class:`zenoh.Config`.

    Args:
        mode: ``"router"`` (needs ``listen``), ``"peer"`` or ``"client"`` (needs ``connect``,
            cannot ``listen``).
        listen: endpoints to listen on, each ``tcp/127.0.0.1:PORT``.
        connect: endpoints to connect to, each ``tcp/127.0.0.1:PORT``.
        connect_timeout_s: how long ``open`` may try the connect endpoints (Zenoh default
            if ``None``; clients fail immediately when nothing listens).
        gossip: enable gossip scouting (only over established links; off by default so
            that peers talk through the router and obey its access control).
        extra: further config values by slash path, e.g.
            ``{"transport/auth/usrpwd/user": "agent"}``; values are JSON-encoded. The
            ``mode``, ``listen``, ``connect`` and ``scouting`` sections are refused.

    Raises:
        ZenohConfigError: unknown mode, missing endpoints, protected ``extra`` keys.
        EndpointError: a non-loopback endpoint.
    """
    if mode not in MODES:
        raise ZenohConfigError(f"mode {mode!r} is not one of {list(MODES)}")
    listen_eps = [check_endpoint(ep) for ep in _as_list(listen, "listen")]
    connect_eps = [check_endpoint(ep) for ep in _as_list(connect, "connect")]
    if mode == "router" and not listen_eps:
        raise ZenohConfigError("a router needs at least one listen endpoint")
    if mode == "client":
        if not connect_eps:
            raise ZenohConfigError("a client needs at least one connect endpoint")
        if listen_eps:
            raise ZenohConfigError("a client cannot listen; use mode='peer'")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("listen/endpoints", json.dumps(listen_eps))
    config.insert_json5("connect/endpoints", json.dumps(connect_eps))
    if connect_timeout_s is not None:
        if not 0 < connect_timeout_s < 3600:
            raise ZenohConfigError("connect_timeout_s must be in (0, 3600)")
        config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", json.dumps(bool(gossip)))
    config.insert_json5("scouting/delay", "0")
    for key, value in (extra or {}).items():
        if key.strip("/").split("/")[0] in _PROTECTED:
            raise ZenohConfigError(f"extra key {key!r} is in a section only make_config sets")
        try:
            config.insert_json5(key, json.dumps(value))
        except zenoh.ZError as exc:
            raise ZenohConfigError(f"invalid config value at {key!r}: {exc}") from exc
    return config


def _as_list(endpoints: Sequence[str], what: str) -> list[str]:
    if isinstance(endpoints, str):
        raise ZenohConfigError(f"{what} must be a sequence of endpoints, not a single string")
    return list(endpoints)


def _json_at(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def check_config(config: zenoh.Config) -> None:
    """Refuse a config that is not loopback-only and multicast-free.

    Checks: mode set, multicast scouting explicitly off, ``listen/endpoints`` and
    ``connect/endpoints`` explicit lists of loopback endpoints.

    Raises:
        ZenohConfigError, EndpointError.
    """
    if not isinstance(config, zenoh.Config):
        raise ZenohConfigError(f"expected a zenoh.Config, got {type(config).__name__}")
    mode = _json_at(config, "mode")
    if mode not in MODES:
        raise ZenohConfigError(f"config mode must be set explicitly to one of {list(MODES)}")
    if _json_at(config, "scouting/multicast/enabled") is not False:
        raise ZenohConfigError("multicast scouting must be disabled explicitly")
    for section in ("listen", "connect"):
        endpoints = _json_at(config, f"{section}/endpoints")
        if not isinstance(endpoints, list):
            raise ZenohConfigError(
                f"{section}/endpoints must be an explicit list (the default listener is tcp/[::]:0)"
            )
        for ep in endpoints:
            check_endpoint(ep)


def open_session(config: zenoh.Config) -> zenoh.Session:
    """Check ``config`` (:func:`check_config`) and open a session. The caller closes it.

    Raises:
        ZenohConfigError: the config is not loopback-only.
        ZenohSessionError: Zenoh failed to open (port in use, nothing to connect to...).
    """
    check_config(config)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        endpoints = _json_at(config, "listen/endpoints") + _json_at(config, "connect/endpoints")
        raise ZenohSessionError(f"cannot open a zenoh session on {endpoints}: {exc}") from exc


@contextmanager
def session_scope(config: zenoh.Config) -> Iterator[zenoh.Session]:
    """Open a session for the ``with`` block and close it on exit (closing undeclares every
    subscriber, queryable and token it declared)."""
    session = open_session(config)
    try:
        yield session
    finally:
        session.close()


def wait_for_match(entity: Any, timeout_s: float = 5.0, poll_s: float = 0.002) -> bool:
    """Wait until a :class:`zenoh.Publisher` or :class:`zenoh.Querier` has a matching
    subscriber/queryable (declarations propagate asynchronously through the router).

    Returns:
        whether a match appeared within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        if entity.matching_status.matching:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


class EmbeddedRouter:
    """A Zenoh router inside this Python process, listening on ``tcp/127.0.0.1:PORT``.

    Args:
        port: TCP port; ``None`` picks a free one (retried if another process grabs it).
        extra: extra config values (see :func:`make_config`), e.g. authentication.

    Use as a context manager, or ``start()`` / ``close()``; ``wait()`` blocks (CLI).
    """

    def __init__(self, port: int | None = None, *, extra: Mapping[str, Any] | None = None) -> None:
        if port is not None:
            loopback_endpoint(port)
        self._requested = port
        self._extra = dict(extra or {})
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
        """``tcp/127.0.0.1:<port>``."""
        return loopback_endpoint(self.port)

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
        state = f"on {self.endpoint}" if self._port is not None and self.running else "stopped"
        return f"EmbeddedRouter({state})"
