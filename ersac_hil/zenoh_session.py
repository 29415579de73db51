"""Zenoh sessions: one configuration resolver, a checked session opener, an embedded router.

Every session this project opens goes through :func:`resolve_config` (command lines: a Zenoh
json5 file ``--zenoh-config``, endpoints ``--zenoh``, ``--insecure``) or :func:`make_config`
(code and tests), then :func:`open_session`, which enforces the rules:

* explicit endpoints only: ``listen/endpoints`` is always set (Zenoh's default listener is
  ``tcp/[::]:0`` on every interface);
* an endpoint off loopback must be secured (``tls/`` or ``quic/``: TLS, with the certificates
  of the json5 file); a plain one is refused unless the user says ``insecure``;
* multicast scouting off unless a config file turns it on *and* ``insecure`` is given; gossip
  scouting off unless asked for; no scouting delay (the default 500 ms only waits for
  multicast replies we never send);
* a bare ``zenoh.Config()`` is refused.

Typical use::

    with EmbeddedRouter() as router:                       # router on 127.0.0.1:<free port>
        with session_scope(router.client_config()) as s:   # closed on exit, even on error
            s.put("ersac/ubot1/learner/kappa", KappaCommand(0.5).to_json())

A router for other processes (CLI): ``EmbeddedRouter(port=7447).start().wait()``.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import os
import re
import socket
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Self

import zenoh

__all__ = [
    "MODES",
    "DEFAULT_ENDPOINT",
    "SECURE_PROTOCOLS",
    "ZenohOptions",
    "add_zenoh_arguments",
    "zenoh_options",
    "resolve_config",
    "is_loopback",
    "split_endpoint",
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
#: Where clients connect and the router listens unless told otherwise.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: Link protocols that are encrypted and authenticated (TLS); fine off loopback.
SECURE_PROTOCOLS: tuple[str, ...] = ("tls", "quic")
_ENDPOINT = re.compile(
    r"(?P<proto>[a-z][a-z0-9-]*)/(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[^/:?#\[\]\s]+)):(?P<port>[0-9]{1,5})"
    r"(?P<rest>[?#][^\s]*)?")
#: Config sections only make_config may set.
_PROTECTED = ("mode", "listen", "connect", "scouting")


class ZenohConfigError(ValueError):
    """A session configuration that this project refuses to use."""


class EndpointError(ZenohConfigError):
    """A malformed endpoint, or one off loopback that is not secured (without ``insecure``)."""


class ZenohSessionError(RuntimeError):
    """Zenoh could not open a session (port in use, no router to connect to...)."""


def loopback_endpoint(port: int, host: str = "127.0.0.1", protocol: str = "tcp") -> str:
    """``tcp/127.0.0.1:<port>`` (or another loopback host / protocol), checked."""
    endpoint = check_endpoint(f"{protocol}/{host}:{port}")
    if not is_loopback(endpoint):
        raise EndpointError(f"{host} is not a loopback address")
    return endpoint


def _parse(endpoint: Any) -> re.Match[str]:
    if not isinstance(endpoint, str):
        raise EndpointError(f"endpoint must be a string, got {type(endpoint).__name__}")
    match = _ENDPOINT.fullmatch(endpoint)
    if match is None or not 1 <= int(match["port"]) <= 65535:
        raise EndpointError(
            f"endpoint {endpoint[:120]!r} is not of the form PROTOCOL/HOST:PORT with a port in "
            "1..65535 (e.g. tcp/127.0.0.1:7447, tls/192.0.2.10:7447, tls/[::1]:7447)")
    return match


def split_endpoint(endpoint: str) -> tuple[str, str, int]:
    """``"tls/[::1]:7447#x=1"`` -> ``("tls", "::1", 7447)``. Raises :class:`EndpointError`."""
    match = _parse(endpoint)
    return match["proto"], match["v6"] or match["host"], int(match["port"])


def is_loopback(endpoint: str) -> bool:
    """Whether ``endpoint`` stays on this machine: a literal loopback address (127.0.0.0/8,
    ``::1``). Host names are not (``localhost`` may resolve anywhere), nor wildcards."""
    match = _parse(endpoint)
    try:
        return ipaddress.ip_address(match["v6"] or match["host"]).is_loopback
    except ValueError:
        return False


def check_endpoint(endpoint: Any, *, insecure: bool = False) -> str:
    """Return ``endpoint`` if it is well formed and either on loopback or secured (``tls/``,
    ``quic/``); a plain endpoint off loopback only with ``insecure``.

    Raises:
        EndpointError: malformed, or unsecured off loopback without ``insecure``.
    """
    match = _parse(endpoint)
    if is_loopback(endpoint) or match["proto"] in SECURE_PROTOCOLS or insecure:
        return endpoint
    secured = f"tls/{match['host'] or '[' + match['v6'] + ']'}:{match['port']}"
    raise EndpointError(
        f"endpoint {endpoint!r} is neither on loopback nor secured: use {secured} with a TLS config "
        "(--zenoh-config FILE; ersac-hil certs init makes one per role), or say --insecure")


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
    insecure: bool = False,
) -> zenoh.Config:
    """Build a :class:`zenoh.Config` in code (command lines use :func:`resolve_config`).

    Args:
        mode: ``"router"`` (needs ``listen``), ``"peer"`` or ``"client"`` (needs ``connect``,
            cannot ``listen``).
        listen: endpoints to listen on, e.g. ``tcp/127.0.0.1:PORT``.
        connect: endpoints to connect to (:func:`check_endpoint`).
        connect_timeout_s: how long ``open`` may try the connect endpoints (Zenoh default
            if ``None``; clients fail immediately when nothing listens).
        gossip: enable gossip scouting (only over established links; off by default so
            that peers talk through the router and obey its access control).
        extra: further config values by slash path, e.g.
            ``{"transport/auth/usrpwd/user": "agent"}``; values are JSON-encoded. The
            ``mode``, ``listen``, ``connect`` and ``scouting`` sections are refused.
        insecure: allow plain endpoints off loopback.

    Raises:
        ZenohConfigError: unknown mode, missing endpoints, protected ``extra`` keys.
        EndpointError: a malformed endpoint, or an unsecured one off loopback.
    """
    if mode not in MODES:
        raise ZenohConfigError(f"mode {mode!r} is not one of {list(MODES)}")
    listen_eps = [check_endpoint(ep, insecure=insecure) for ep in _as_list(listen, "listen")]
    connect_eps = [check_endpoint(ep, insecure=insecure) for ep in _as_list(connect, "connect")]
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
            raise ZenohConfigError(f"invalid config value at {key!r}: {zenoh_reason(exc)}") from exc
    return config


def _as_list(endpoints: Sequence[str], what: str) -> list[str]:
    if isinstance(endpoints, str):
        raise ZenohConfigError(f"{what} must be a sequence of endpoints, not a single string")
    return list(endpoints)


def _json_at(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def check_config(config: zenoh.Config, *, insecure: bool = False) -> None:
    """Refuse a config that could leave this machine unsecured or listens by default.

    Checks: mode set; ``listen/endpoints`` and ``connect/endpoints`` explicit lists whose
    endpoints are on loopback or secured (:func:`check_endpoint`); multicast scouting
    explicitly off (on only with ``insecure``).

    Raises:
        ZenohConfigError, EndpointError.
    """
    if not isinstance(config, zenoh.Config):
        raise ZenohConfigError(f"expected a zenoh.Config, got {type(config).__name__}")
    mode = _json_at(config, "mode")
    if mode not in MODES:
        raise ZenohConfigError(f"config mode must be set explicitly to one of {list(MODES)}")
    multicast = _json_at(config, "scouting/multicast/enabled")
    if multicast is not False and not (multicast is True and insecure):
        raise ZenohConfigError("multicast scouting must be disabled explicitly "
                               "(it is only allowed on with --insecure)")
    for section in ("listen", "connect"):
        endpoints = _json_at(config, f"{section}/endpoints")
        if not isinstance(endpoints, list):
            raise ZenohConfigError(
                f"{section}/endpoints must be an explicit list (the default listener is tcp/[::]:0)"
            )
        for ep in endpoints:
            check_endpoint(ep, insecure=insecure)


def open_session(config: zenoh.Config, *, insecure: bool = False) -> zenoh.Session:
    """Check ``config`` (:func:`check_config`) and open a session. The caller closes it.

    Raises:
        ZenohConfigError: the config breaks a rule of :func:`check_config`.
        ZenohSessionError: Zenoh failed to open (port in use, nothing to connect to, TLS
            handshake refused...).
    """
    check_config(config, insecure=insecure)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        endpoints = _json_at(config, "listen/endpoints") + _json_at(config, "connect/endpoints")
        raise ZenohSessionError(f"cannot open a zenoh session on {endpoints}: {zenoh_reason(exc)}") from exc


_RUST_SOURCE = re.compile(r"\s+at \S+\.rs:\d+\.?")


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's error text without the Rust source locations it appends (`` at /.../x.rs:388.``):
    the build machine's paths tell a user nothing."""
    return _RUST_SOURCE.sub("", str(exc)).strip()


# --------------------------------------------------------------------------- command lines


@dataclass(frozen=True)
class ZenohOptions:
    """What a command line says about its Zenoh session.

    Attributes:
        endpoints: ``--zenoh`` (repeatable): where a client or peer connects, where a router
            listens. Empty: the config file's, else :data:`DEFAULT_ENDPOINT`.
        config_file: ``--zenoh-config``: a Zenoh json5 configuration (the format of ``zenohd``
            and every Zenoh client: TLS certificates, access control, timeouts...).
        insecure: ``--insecure``: allow plain endpoints off loopback (and multicast scouting
            if the file turns it on).
    """

    endpoints: tuple[str, ...] = ()
    config_file: str | None = None
    insecure: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.endpoints, str):
            raise ZenohConfigError("endpoints must be a sequence of endpoints, not a single string")
        object.__setattr__(self, "endpoints", tuple(self.endpoints))
        if self.config_file is not None:
            object.__setattr__(self, "config_file", os.fspath(self.config_file))


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, listens: bool = False) -> None:
    """``--zenoh ENDPOINT`` (repeatable), ``--zenoh-config FILE``, ``--insecure``."""
    where = "listen on" if listens else "connect to"
    parser.add_argument(
        "--zenoh", action="append", metavar="ENDPOINT",
        help=f"endpoint to {where}, repeatable (default: the --zenoh-config file's, else "
             f"{DEFAULT_ENDPOINT}); off loopback only tls/HOST:PORT unless --insecure")
    parser.add_argument(
        "--zenoh-config", dest="zenoh_config", metavar="FILE",
        help="Zenoh json5 configuration (TLS certificates, access control...); "
             "ersac-hil certs init writes one per role")
    parser.add_argument(
        "--insecure", action="store_true",
        help="allow plain (unencrypted, unauthenticated) endpoints off loopback")


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """The :class:`ZenohOptions` of parsed :func:`add_zenoh_arguments` flags."""
    return ZenohOptions(tuple(args.zenoh or ()), args.zenoh_config, bool(args.insecure))


def _file_endpoints(config: zenoh.Config, section: str, mode: str) -> list[str] | None:
    """A file's explicit endpoint list for ``mode`` (a list, or a per-mode map), else None."""
    value = _json_at(config, f"{section}/endpoints")
    if isinstance(value, dict):
        value = value.get(mode)
    return list(value) if isinstance(value, list) else None


def resolve_config(
    options: ZenohOptions = ZenohOptions(),
    *,
    mode: str = "client",
    listen: Sequence[str] = (),
    connect_timeout_s: float | None = None,
) -> zenoh.Config:
    """The session configuration of a command: the one place every command resolves it.

    Precedence (python-can style): explicit arguments, then the json5 file, then defaults.

    * ``mode`` is the command's (a router is a router, whatever the file says);
    * endpoints: ``options.endpoints`` (a router listens on them, others connect to them),
      else the file's, else :data:`DEFAULT_ENDPOINT`; a client never listens; ``listen``
      gives a peer's listeners;
    * scouting: multicast off and gossip off unless the file sets them, no scouting delay;
    * everything else (TLS certificates, access control, timeouts) comes from the file.

    The result passes :func:`check_config` with ``options.insecure``.

    Raises:
        ZenohConfigError: unreadable or invalid file, unknown mode, insecure endpoints.
    """
    if mode not in MODES:
        raise ZenohConfigError(f"mode {mode!r} is not one of {list(MODES)}")
    if options.config_file is None:
        config = zenoh.Config()
    else:
        path = options.config_file
        if not os.path.isfile(path):
            raise ZenohConfigError(f"zenoh config {path}: no such file")
        try:
            config = zenoh.Config.from_file(path)
        except (zenoh.ZError, ValueError) as exc:
            raise ZenohConfigError(f"zenoh config {path} is not a valid Zenoh json5 config: "
                                   f"{zenoh_reason(exc)}") from None
    given = list(options.endpoints)
    file_listen = _file_endpoints(config, "listen", mode)
    file_connect = _file_endpoints(config, "connect", mode)
    if mode == "router":
        listen_eps = given or file_listen or [DEFAULT_ENDPOINT]
        connect_eps = file_connect or []
    else:
        connect_eps = given or file_connect or [DEFAULT_ENDPOINT]
        listen_eps = [] if mode == "client" else list(listen) or file_listen or []
    try:
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("listen/endpoints", json.dumps(listen_eps))
        config.insert_json5("connect/endpoints", json.dumps(connect_eps))
        for key, default in (("scouting/multicast/enabled", False), ("scouting/gossip/enabled", False),
                             ("scouting/delay", 0)):
            if _json_at(config, key) is None:
                config.insert_json5(key, json.dumps(default))
        if connect_timeout_s is not None:
            config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"invalid zenoh endpoints {listen_eps + connect_eps}: {zenoh_reason(exc)}") from None
    check_config(config, insecure=options.insecure)
    return config


@contextmanager
def session_scope(config: zenoh.Config, *, insecure: bool = False) -> Iterator[zenoh.Session]:
    """Open a session for the ``with`` block and close it on exit (closing undeclares every
    subscriber, queryable and token it declared)."""
    session = open_session(config, insecure=insecure)
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
            self._endpoint = _json_at(self._config, "listen/endpoints")[0]
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
