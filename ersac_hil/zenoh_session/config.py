"""Building and checking session configurations: :func:`make_config` (code and tests),
:func:`resolve_config` (command lines: :class:`ZenohOptions`), :func:`check_config` (the rules
every session obeys)."""
from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from .endpoints import DEFAULT_ENDPOINT, check_endpoint
from .errors import ZenohConfigError, zenoh_reason

__all__ = ["MODES", "BURSTS", "ZenohOptions", "make_config", "check_config", "resolve_config", "json_at",
           "tolerate_bursts"]

#: Zenoh session modes.
MODES: tuple[str, ...] = ("router", "peer", "client")
#: Transmission settings for a session that publishes in bursts with congestion control
#: ``DROP`` (the ROS 2 feed catching up after a lag; a router whose subscriber shares a busy
#: interpreter): 16 batches of the data priority (Zenoh's default: 2, 128 kB) and 50 ms before a
#: sample is dropped (default 1 ms), so a transmit thread preempted for a few time slices on a
#: loaded machine drops nothing. A congested link still drops: Zenoh waits once, then drops at
#: once while the queue stays full (measured: 30000 puts of 1 kB to a stopped router take
#: 0.075 s, the worst one 50.5 ms). Applied by :func:`tolerate_bursts`.
BURSTS: Mapping[str, int] = {
    "transport/link/tx/queue/size/data": 16,
    "transport/link/tx/queue/congestion_control/drop/wait_before_drop": 50_000,  # us
}
#: Config sections only make_config may set.
_PROTECTED = ("mode", "listen", "connect", "scouting")


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


def json_at(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def tolerate_bursts(config: zenoh.Config) -> zenoh.Config:
    """Raise each :data:`BURSTS` setting of ``config`` that is still Zenoh's default (a value
    the user's config file chose stays); returns ``config``."""
    default = zenoh.Config()
    for key, value in BURSTS.items():
        if json_at(config, key) == json_at(default, key):
            config.insert_json5(key, json.dumps(value))
    return config


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
    mode = json_at(config, "mode")
    if mode not in MODES:
        raise ZenohConfigError(f"config mode must be set explicitly to one of {list(MODES)}")
    multicast = json_at(config, "scouting/multicast/enabled")
    if multicast is not False and not (multicast is True and insecure):
        raise ZenohConfigError("multicast scouting must be disabled explicitly "
                               "(it is only allowed on with --insecure)")
    for section in ("listen", "connect"):
        endpoints = json_at(config, f"{section}/endpoints")
        if not isinstance(endpoints, list):
            raise ZenohConfigError(
                f"{section}/endpoints must be an explicit list (the default listener is tcp/[::]:0)"
            )
        for ep in endpoints:
            check_endpoint(ep, insecure=insecure)



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


def _file_endpoints(config: zenoh.Config, section: str, mode: str) -> list[str] | None:
    """A file's explicit endpoint list for ``mode`` (a list, or a per-mode map), else None."""
    value = json_at(config, f"{section}/endpoints")
    if isinstance(value, dict):
        value = value.get(mode)
    return list(value) if isinstance(value, list) else None


def resolve_config(
    options: ZenohOptions = ZenohOptions(),
    *,
    mode: str = "client",
    listen: Sequence[str] = (),
    connect_timeout_s: float | None = None,
    default_connect_timeout_s: float | None = None,
) -> zenoh.Config:
    """The session configuration of a command: the one place every command resolves it.

    Precedence (python-can style): explicit arguments, then the json5 file, then defaults.

    * ``mode`` is the command's (a router is a router, whatever the file says);
    * endpoints: ``options.endpoints`` (a router listens on them, others connect to them),
      else the file's, else :data:`DEFAULT_ENDPOINT`; a client never listens; ``listen``
      gives a peer's listeners;
    * scouting: multicast off and gossip off unless the file sets them, no scouting delay;
    * the connect timeout: ``connect_timeout_s`` (explicit), else the file's
      ``connect/timeout_ms``, else ``default_connect_timeout_s`` (the command's), else Zenoh's;
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
            if json_at(config, key) is None:
                config.insert_json5(key, json.dumps(default))
        if connect_timeout_s is None and json_at(config, "connect/timeout_ms") is None:
            connect_timeout_s = default_connect_timeout_s
        if connect_timeout_s is not None:
            config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"invalid zenoh endpoints {listen_eps + connect_eps}: {zenoh_reason(exc)}") from None
    check_config(config, insecure=options.insecure)
    return config
