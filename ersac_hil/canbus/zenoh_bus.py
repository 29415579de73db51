"""CAN over Zenoh: a python-can interface plugin (``interface="zenoh"``).

Every bus on a channel publishes its frames on one Zenoh key, ``<prefix>/<channel>``
(default prefix ``can``), and subscribes to it; the Zenoh router does the fan-out, so every
frame one bus sends reaches every other bus of the channel, in the order each sender sent
them, across processes and machines (like a CAN-over-Ethernet gateway). Registered as the
``can.interface`` entry point ``zenoh``, so python-can and canopen users open it as::

    can.Bus(interface="zenoh", channel="can0", connect="tcp/127.0.0.1:7447")
    can.Bus(interface="zenoh", channel="can0@tcp/127.0.0.1:7447")     # the same, one string

Each bus is its own Zenoh client session (``ersac_hil.zenoh_session.make_config``, so the
project's endpoint rules apply: explicit endpoints, no multicast scouting); it does not hear
its own frames unless ``receive_own_messages=True``. Delivery is reliable and blocking
(congestion control ``BLOCK``, one priority, so frames are never dropped or reordered).
Periodic sends use python-can's thread-based tasks (``modify_data`` works).

Push delivery (optional, :meth:`ZenohBus.push_notifier`): instead of a ``can.Notifier`` thread
polling ``recv()``, the listeners run on Zenoh's receive thread as each frame arrives - one
thread hand-over less per frame, which is most of a lock-step cycle's latency on a loaded
machine. ``protocol.can.busconfig.open_network`` uses it for canopen networks; listeners run
one frame at a time, in arrival order, and a listener's exception is kept (``exception``)
like ``can.Notifier`` does.

Bursts: :meth:`ZenohBus.send_many` puts several frames in one sample (a simulator's TPDOs
after a SYNC, a master's RPDOs and the SYNC): one Zenoh message and one receive callback
instead of one per frame; receivers see the frames one by one, in order, as if sent singly.

Wire format of one sample: one or more frames back to back, each (little-endian)
``u32 arbitration_id``, ``u8 flags`` (bit 0 extended id, 1 remote, 2 error frame, 3 CAN FD,
4 bit-rate switch, 5 error-state indicator), ``u8 dlc``, ``u8 length``, then ``length`` data
bytes.
"""
from __future__ import annotations

import queue
import struct
import time
from collections.abc import Sequence
from typing import Any

import can
import zenoh
from can.bus import BusABC, CanProtocol

from ersac_hil.zenoh_session import ZenohConfigError, make_config, open_session
from protocol.zenoh.errors import KeySpaceError
from protocol.zenoh.keys import validate_chunk

__all__ = ["ZenohBus", "PushNotifier", "DEFAULT_PREFIX", "encode_frame", "decode_frame", "decode_frames",
           "parse_channel"]

DEFAULT_PREFIX = "can"
_HEADER = struct.Struct("<IBBB")
_EXTENDED, _REMOTE, _ERROR, _FD, _BRS, _ESI = (1 << i for i in range(6))


def encode_frame(msg: can.Message) -> bytes:
    """The wire form of ``msg`` (see the module doc); a sample carries one or more."""
    flags = ((_EXTENDED if msg.is_extended_id else 0) | (_REMOTE if msg.is_remote_frame else 0)
             | (_ERROR if msg.is_error_frame else 0) | (_FD if msg.is_fd else 0)
             | (_BRS if msg.bitrate_switch else 0) | (_ESI if msg.error_state_indicator else 0))
    data = bytes(msg.data)
    return _HEADER.pack(msg.arbitration_id, flags, msg.dlc, len(data)) + data


def decode_frames(payload: bytes, channel: str | None = None) -> list[can.Message]:
    """Every frame of a sample, as received ``can.Message`` objects timestamped now.

    Raises:
        ValueError: a payload that does not split into whole frames.
    """
    out, at, end, now = [], 0, len(payload), time.time()
    while at < end:
        if end - at < _HEADER.size:
            raise ValueError(f"CAN-over-Zenoh sample: {end - at} bytes left, shorter than a frame header")
        arbitration_id, flags, dlc, length = _HEADER.unpack_from(payload, at)
        at += _HEADER.size
        if end - at < length:
            raise ValueError(f"CAN-over-Zenoh sample: frame 0x{arbitration_id:X} needs {length} data bytes, "
                             f"{end - at} left")
        out.append(can.Message(timestamp=now, arbitration_id=arbitration_id,
                               is_extended_id=bool(flags & _EXTENDED), is_remote_frame=bool(flags & _REMOTE),
                               is_error_frame=bool(flags & _ERROR), is_fd=bool(flags & _FD),
                               bitrate_switch=bool(flags & _BRS), error_state_indicator=bool(flags & _ESI),
                               dlc=dlc, data=payload[at:at + length], channel=channel, is_rx=True,
                               check=False))
        at += length
    if not out:
        raise ValueError("CAN-over-Zenoh sample without a frame")
    return out


def decode_frame(payload: bytes, channel: str | None = None) -> can.Message:
    """The single frame of a sample (see :func:`decode_frames`)."""
    frames = decode_frames(payload, channel)
    if len(frames) != 1:
        raise ValueError(f"CAN-over-Zenoh sample with {len(frames)} frames, expected one")
    return frames[0]


def parse_channel(channel: Any, connect: str | Sequence[str] | None = None) -> tuple[str, tuple[str, ...]]:
    """``(channel name, endpoints)`` from ``"name"`` plus ``connect``, or ``"name@ep[,ep...]"``.

    Raises:
        can.CanInterfaceNotImplementedError: never; ``ValueError`` for a bad channel.
    """
    if not isinstance(channel, str) or not channel:
        raise ValueError(f"zenoh CAN channel must be a non-empty string, got {channel!r}")
    name, _, inline = channel.partition("@")
    endpoints: list[str] = [e for e in inline.split(",") if e] if inline else []
    if connect is not None:
        endpoints += [e for e in connect.split(",") if e] if isinstance(connect, str) else list(connect)
    try:
        validate_chunk(name, "zenoh CAN channel name")
    except KeySpaceError as exc:
        raise ValueError(str(exc)) from None
    if not endpoints:
        raise ValueError(f"zenoh CAN channel {name!r}: no Zenoh endpoint (channel 'name@tcp/HOST:PORT' "
                         "or connect=...)")
    return name, tuple(endpoints)


class ZenohBus(BusABC):
    """A python-can bus whose frames travel as Zenoh samples (see the module doc).

    Args:
        channel: ``"name"`` (with ``connect``) or ``"name@tcp/HOST:PORT[,...]"``.
        connect: Zenoh endpoints to connect to (string, comma-separated, or sequence).
        prefix: key prefix of the channel's key (default ``can``).
        receive_own_messages: also receive the frames this bus sends.
        mode: Zenoh session mode, ``client`` (default, through the router) or ``peer``.
        connect_timeout: s to keep trying the endpoints when opening.
        **kwargs: other python-can arguments (``bitrate``, ``can_filters``...); bit rate
            has no meaning here and is ignored.

    Raises:
        can.CanInitializationError: bad channel or endpoints, or no Zenoh session.
    """

    def __init__(self, channel: Any = None, can_filters=None, *, connect: str | Sequence[str] | None = None,  # noqa: ANN001
                 prefix: str = DEFAULT_PREFIX, receive_own_messages: bool = False,
                 mode: str = "client", connect_timeout: float = 10.0, **kwargs: Any) -> None:
        try:
            name, endpoints = parse_channel(channel, connect)
            config = make_config(mode, connect=list(endpoints), connect_timeout_s=float(connect_timeout))
            for chunk in str(prefix).split("/"):
                validate_chunk(chunk, "zenoh CAN key prefix")
        except (ValueError, ZenohConfigError, KeySpaceError) as exc:
            raise can.CanInitializationError(str(exc)) from None
        self.key = f"{prefix}/{name}"
        self.channel_info = f"CAN over Zenoh on {self.key} via {','.join(endpoints)}"
        self._name = name
        self._rx: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._push: PushNotifier | None = None
        try:
            self._session = open_session(config)
        except Exception as exc:  # noqa: BLE001 - ZenohSessionError and whatever zenoh raises
            raise can.CanInitializationError(f"{self.channel_info}: {exc}") from None
        origin = zenoh.Locality.ANY if receive_own_messages else zenoh.Locality.REMOTE
        self._publisher = self._session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.BLOCK, express=False,
            reliability=zenoh.Reliability.RELIABLE)
        self._subscriber = self._session.declare_subscriber(self.key, self._on_sample,
                                                            allowed_origin=origin)
        self._closed = False
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            frames = decode_frames(sample.payload.to_bytes(), self._name)
        except ValueError:
            return  # not frames: nothing a CAN node could receive
        push = self._push
        for msg in frames:
            if push is None:
                self._rx.put(msg)
            elif self._matches_filters(msg):
                push.deliver(msg)

    def push_notifier(self, listeners: list) -> PushNotifier:  # noqa: ANN001
        """Deliver every received frame to ``listeners`` (``can.Listener`` or callables) on
        Zenoh's receive thread from now on, instead of queueing it for ``recv()``. Stop it
        with the returned object's ``stop()`` (what ``can.Notifier`` users call)."""
        if self._push is not None:
            raise can.CanOperationError(f"{self.channel_info}: a push notifier is already attached")
        self._push = PushNotifier(self, listeners)
        return self._push

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            return self._rx.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._put(encode_frame(msg))

    def send_many(self, msgs: Sequence[can.Message]) -> None:
        """Send ``msgs`` in this order as one burst (one Zenoh sample, see the module doc)."""
        if msgs:
            self._put(b"".join([encode_frame(m) for m in msgs]))

    def _put(self, payload: bytes) -> None:
        if self._closed:
            raise can.CanOperationError(f"{self.channel_info}: bus is shut down")
        try:
            self._publisher.put(payload)
        except zenoh.ZError as exc:
            raise can.CanOperationError(f"{self.channel_info}: {exc}") from exc

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        for entity in (self._subscriber, self._publisher):
            try:
                entity.undeclare()
            except zenoh.ZError:
                pass
        self._session.close()


class PushNotifier:
    """The ``can.Notifier`` interface canopen uses (``add_listener``, ``remove_listener``,
    ``stop``, ``exception``) for frames pushed by a :class:`ZenohBus` (see the module doc)."""

    def __init__(self, bus: ZenohBus, listeners: list) -> None:  # noqa: ANN001
        self.bus = bus
        self.listeners = listeners
        self.exception: Exception | None = None
        self._stopped = False

    def deliver(self, msg: can.Message) -> None:
        if self._stopped or self.exception is not None:
            return
        try:
            for listener in self.listeners:
                callback = getattr(listener, "on_message_received", listener)
                callback(msg)
        except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
            self.exception = exc
            for listener in self.listeners:
                on_error = getattr(listener, "on_error", None)
                if on_error is not None:
                    on_error(exc)

    def add_listener(self, listener) -> None:  # noqa: ANN001
        self.listeners.append(listener)

    def remove_listener(self, listener) -> None:  # noqa: ANN001
        self.listeners.remove(listener)

    @property
    def stopped(self) -> bool:
        return self._stopped

    def stop(self, timeout: float = 5.0) -> None:  # noqa: ARG002 - nothing to join
        self._stopped = True
        if self.bus._push is self:
            self.bus._push = None
        for listener in self.listeners:
            stop = getattr(listener, "stop", None)
            if stop is not None:
                stop()
