"""How either side reaches the CAN bus: a typed ``BusConfig`` and one ``open_bus`` factory.

Backends are plain python-can configurations, never hard-wired:

* ``socketcan`` on ``vcan0``/``can0`` where the kernel has SocketCAN (the real robot);
* ``remote`` to a loopback hub (``ersac-hil bus``, python-can-remote on 127.0.0.1) on
  machines without SocketCAN, channel ``ws://127.0.0.1:PORT/``;
* ``virtual`` for single-process tests;
* ``zenoh``: CAN over Zenoh (``ersac_hil.canbus.zenoh_bus``), channel ``name@tcp/127.0.0.1:PORT``;
  ``zenoh_config=FILE`` (a role's TLS config) for a secured router.

``resolve_bus_config`` honours python-can's own resolution (``can.util.load_config``:
environment ``CAN_INTERFACE``/``CAN_CHANNEL``/``CAN_BITRATE``/``CAN_CONFIG`` and ``~/.canrc``)
for whatever the caller leaves unset; further keyword arguments of the interface come from
there or from ``--bus-kwargs KEY=VALUE ...`` (python-can's own flag, :func:`parse_bus_kwargs`),
and travel as strings in ``BusConfig.options``. ``open_bus`` creates the bus object and
nothing else: no threads are started here, the caller owns (and must ``shutdown()``) what it
gets.
"""
from __future__ import annotations

import ipaddress
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from urllib.parse import urlparse

import can
import canopen

from protocol.can.devices import BITRATE as DEFAULT_BITRATE  # the default robot description's

from .fastpath import BurstSender, FramePusher

log = logging.getLogger(__name__)


class BusConfigError(ValueError):
    """The bus configuration is incomplete or not allowed (e.g. a non-loopback hub)."""


@dataclass(frozen=True)
class BusConfig:
    interface: str
    channel: str
    bitrate: int = DEFAULT_BITRATE
    options: tuple[tuple[str, str], ...] = field(default=())

    def __post_init__(self) -> None:
        if not self.interface or not self.channel:
            raise BusConfigError("a CAN bus needs an interface and a channel")
        if self.bitrate <= 0:
            raise BusConfigError(f"bitrate must be positive, got {self.bitrate}")
        if self.interface == "remote":
            _check_loopback_url(self.channel)
        if self.interface == "udp_multicast":
            raise BusConfigError("udp_multicast is not allowed: this project stays on loopback")

    def kwargs(self) -> dict:
        kw = {"interface": self.interface, "channel": self.channel, **dict(self.options)}
        if self.interface not in ("virtual", "remote"):
            kw["bitrate"] = self.bitrate
        if self.interface == "virtual":
            kw.setdefault("receive_own_messages", False)
        return kw

    def describe(self) -> str:
        return f"{self.interface}:{self.channel}"


def _check_loopback_url(url: str) -> None:
    parsed = urlparse(url)
    if parsed.scheme not in ("ws", "wss") or not parsed.hostname:
        raise BusConfigError(f"remote channel must be ws://127.0.0.1:PORT/, got {url!r}")
    host = parsed.hostname
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise BusConfigError(f"remote CAN hub must be on loopback, got host {host!r}")


_BUS_KWARG = re.compile(r"(?P<key>[_a-zA-Z][_a-zA-Z0-9]*)=(?P<value>\S*)")
_OWN_KEYS = ("interface", "channel", "bitrate")


def parse_bus_kwargs(items: Sequence[str] | None) -> tuple[tuple[str, str], ...]:
    """``["zenoh_config=a.json5", "insecure=true"]`` -> options of a :class:`BusConfig`
    (python-can's ``--bus-kwargs`` syntax; values stay strings).

    Raises:
        BusConfigError: an item not of the form KEY=VALUE, or one that sets interface,
            channel or bitrate (they have their own flags).
    """
    options: dict[str, str] = {}
    for item in items or ():
        match = _BUS_KWARG.fullmatch(item)
        if match is None:
            raise BusConfigError(f"--bus-kwargs: {item!r} is not KEY=VALUE")
        if match["key"] in _OWN_KEYS:
            raise BusConfigError(f"--bus-kwargs: set {match['key']} with --bus-{match['key']}, not here")
        options[match["key"]] = match["value"]
    return tuple(options.items())


def resolve_bus_config(interface: str | None = None, channel: str | None = None,
                       bitrate: int | None = None, options: Sequence[tuple[str, str]] = (),
                       default_bitrate: int = DEFAULT_BITRATE) -> BusConfig:
    """Fill what the caller left ``None`` from python-can's configuration resolution;
    ``options`` (:func:`parse_bus_kwargs`) override the configured keyword arguments; a bit
    rate neither given nor configured is ``default_bitrate`` (the robot description's)."""
    given = {k: v for k, v in (("interface", interface), ("channel", channel),
                               ("bitrate", bitrate)) if v is not None} | dict(options)
    nothing = ("no CAN interface/channel given and none configured "
               "(CAN_INTERFACE/CAN_CHANNEL or ~/.canrc)")
    try:
        resolved = can.util.load_config(config=given)
    except can.CanInterfaceNotImplementedError as exc:  # python-can: 'Unknown interface type "None"'
        raise BusConfigError(str(exc) if interface is not None else nothing) from exc
    if not resolved.get("interface") or resolved.get("channel") in (None, ""):
        raise BusConfigError(nothing)
    extra = tuple((k, str(v)) for k, v in resolved.items() if k not in _OWN_KEYS)
    return BusConfig(str(resolved["interface"]), str(resolved["channel"]),
                     int(resolved.get("bitrate") or default_bitrate), extra)


def unavailable_reason(config: BusConfig, exc: Exception) -> str:
    """Why opening ``config`` failed with ``exc``, in words a user can act on."""
    errno = getattr(exc, "errno", None)
    if config.interface == "socketcan" and errno == 97:
        return "the kernel has no SocketCAN (CONFIG_CAN unset: address family not supported)"
    if config.interface == "socketcan" and errno == 19:
        return (f"no {config.channel} interface (create it: ip link add {config.channel} type vcan "
                f"&& ip link set {config.channel} up)")
    if config.interface == "remote" and isinstance(exc, OSError):
        return f"no CAN hub answers at {config.channel} ({exc.strerror or exc}; start one: ersac-hil bus)"
    return f"{config.describe()}: {exc}"


def probe_bus(config: BusConfig) -> None:
    """Open and close ``config`` once; ``BusConfigError`` saying why when it cannot be opened."""
    try:
        bus = open_bus(config)
    except (OSError, ImportError, can.CanError, ValueError) as exc:
        raise BusConfigError(f"cannot open CAN bus {config.describe()}: {unavailable_reason(config, exc)}") from exc
    bus.shutdown()


def open_bus(config: BusConfig) -> can.BusABC:
    """Open the python-can bus described by ``config`` (caller shuts it down)."""
    return can.Bus(**config.kwargs())


NOTIFIER_CYCLE_S = 0.05
"""How long the notifier blocks in ``recv``: bounds how long ``disconnect()`` takes
(canopen's default of 1 s made every shutdown over the hub last a second)."""


class Network(canopen.Network):
    """canopen's ``Network`` with the bus's declared fast paths (``protocol.can.fastpath``)
    looked up once, when :func:`open_network` opens it: ``burst`` is the bus if it is a
    ``BurstSender``, else ``None``."""

    burst: BurstSender | None = None


def open_network(config: BusConfig) -> Network:
    """A connected canopen ``Network`` on a new bus (``disconnect()`` closes both).

    A bus that pushes frames to listeners on its own receive thread (a
    ``fastpath.FramePusher``, e.g. CAN over Zenoh) gets no ``can.Notifier`` polling thread:
    one thread hand-over less per frame."""
    bus = open_bus(config)
    network = Network(bus)
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
    network.burst = bus if isinstance(bus, BurstSender) else None
    if not isinstance(bus, FramePusher):
        return network.connect()
    network.listeners[:] = [FrameListener(network)]
    network.notifier = bus.push_notifier(network.listeners)
    return network


class FrameListener(canopen.network.MessageListener):
    """canopen's listener (frames to ``Network.notify``) that also takes a data frame as
    ``on_frame(can_id, data, timestamp)``, so a bus that pushes frames that way (CAN over
    Zenoh) builds no ``can.Message`` for it."""

    def on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            self.network.notify(can_id, data, timestamp)
        except Exception as exc:  # like MessageListener: a callback's error does not stop the bus
            log.error(str(exc))


def send_frames(network: Network, frames: list[tuple[int, bytes]]) -> None:
    """Send standard-id data frames ``(COB-ID, data)`` in this order: as one burst where the
    bus is a ``fastpath.BurstSender`` (CAN over Zenoh: one message for a SYNC's worth of
    PDOs), else one by one (``Network.send_message``)."""
    burst = network.burst
    if burst is None:
        for cob_id, data in frames:
            network.send_message(cob_id, data)
        return
    with network.send_lock:
        burst.send_data_frames(frames)
    network.check()
