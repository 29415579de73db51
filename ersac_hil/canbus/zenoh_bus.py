"""CAN over Zenoh: a python-can interface plugin (``interface="zenoh"``).

Every bus on a channel publishes its frames on one Zenoh key, ``<prefix>/<channel>``
(default prefix ``can``), and subscribes to it; the Zenoh router does the fan-out, so every
frame one bus sends reaches every other bus of the channel, in the order each sender sent
them, across processes and machines (like a CAN-over-Ethernet gateway). Registered as the
``can.interface`` entry point ``zenoh``, so python-can and canopen users open it as::

    can.Bus(interface="zenoh", channel="can0", connect="tcp/127.0.0.1:7447")
    can.Bus(interface="zenoh", channel="can0@tcp/127.0.0.1:7447")     # the same, one string

Each bus is its own Zenoh client session, configured like every other session of the project
(``ersac_hil.zenoh_session.resolve_config``: the endpoints of the channel, ``connect`` or the
file, explicit endpoints, no multicast scouting, plain endpoints off loopback only with
``insecure``). ``zenoh_config`` is a Zenoh json5 file (``--zenoh-config`` of the commands):
TLS with a client certificate, so the bus runs through a secured router under a role's
identity (``ersac-hil certs init`` writes one per role; its access control lets the ``agent``
and ``simulator`` roles use the ``can/**`` keys)::

    can.Bus(interface="zenoh", channel="can0@tls/127.0.0.1:7447", zenoh_config="certs/agent.json5")
    can.Bus(interface="zenoh", channel="can0", zenoh_config="certs/simulator.json5")  # its router

A direct link without the router (``ersac_hil.canbus.direct``): one bus listens, the others
connect to it (it routes between them), with the router's TLS and access control when it has
a role's certificate::

    can.Bus(interface="zenoh", channel="can0", listen="tls/127.0.0.1:7450", zenoh_config="certs/simulator.json5")
    can.Bus(interface="zenoh", channel="can0@tls/127.0.0.1:7450", zenoh_config="certs/agent.json5")

python-can's own configuration (``~/.canrc``, ``CAN_CONFIG``) and ``--bus-kwargs`` give these
as strings; they are read like the keyword arguments. A bus does not hear its own frames
unless ``receive_own_messages=True``. Delivery is reliable and blocking
(congestion control ``BLOCK``, one priority, so frames are never dropped or reordered).
Periodic sends use python-can's thread-based tasks (``modify_data`` works).

Each bus's session asks for Zenoh's low-latency transport (``lowlatency=True``, the default:
``transport/unicast/lowlatency`` on, QoS off, which it excludes): a frame is written to the link
by the thread that sends it, with no batching task in between - a direct link's lock-step
cycle runs 3-24 % more cycles a second with it on this machine (docs/performance.md). It is
negotiated per link: where the other end does not ask for it (a router's default session),
the link is Zenoh's universal transport as before. ``lowlatency=False`` leaves the transport
to the defaults or the ``zenoh_config`` file.

Busy polling (``busy_poll=SECONDS``, off by default): the bus takes its samples from Zenoh
on a receive thread of its own that, after each sample, keeps asking for the next one
(yielding the processor and the GIL between tries) for ``busy_poll`` seconds before it
blocks. A lock-step cycle's answer arrives a few hundred microseconds after its question: a
thread that polls gets it without being woken, and its processor never idles in between (on
a virtual machine an idle processor costs tens of microseconds to wake, on every hop). It
costs a processor's time while frames flow, at most ``busy_poll`` after the last one: for
simulated robots in lock-step where there is a core for each polling bus (``ersac-hil
demo``, ``Stack`` and the benchmarks, ``ersac_hil.stack.busy_poll_for``), not for a robot's
real-time bus (a frame every 5 ms outlasts the window). The delivery is the same:
every frame, in order, to ``recv()`` or the push listeners, on one thread.

Push delivery (optional, :meth:`ZenohBus.push_notifier`): instead of a ``can.Notifier`` thread
polling ``recv()``, the listeners run on Zenoh's receive thread as each frame arrives - one
thread hand-over less per frame, which is most of a lock-step cycle's latency on a loaded
machine. ``protocol.can.busconfig.open_network`` uses it for canopen networks; listeners run
one frame at a time, in arrival order, and a listener's exception is kept (``exception``)
like ``can.Notifier`` does.

Bursts: :meth:`ZenohBus.send_many` puts several frames in one sample (a simulator's TPDOs
after a SYNC, a master's RPDOs and the SYNC): one Zenoh message and one receive callback
instead of one per frame; receivers see the frames one by one, in order, as if sent singly.

Without ``can.Message`` on the cyclic path: :meth:`ZenohBus.send_data_frames` sends
standard-id data frames given as ``(arbitration id, data)`` (the same wire bytes as
``send_many`` of the equivalent messages), and a pushed listener with an ``on_frame(can_id,
data, timestamp)`` method (canopen's ``Network.notify`` signature) gets the received data
frames that way, without a ``can.Message`` built for it (data as a ``bytearray``, like a
message's; error and remote frames are not given to ``on_frame``; with ``can_filters`` set
every listener gets messages).

A whole sample at once (:meth:`PushNotifier.intercept`): an interceptor gets the frames of
each sample in one call, as ``protocol.can.fastpath.Frame`` tuples, before the listeners (and before
``can_filters``); it consumes the frames it handles and returns the others, which the
listeners then get as usual - e.g. the agent takes the TPDOs of a SYNC with one call and one
lock per burst instead of per frame and hands canopen the rest.

Wire format of one sample: one or more frames back to back, each (little-endian)
``u32 arbitration_id``, ``u8 flags`` (bit 0 extended id, 1 remote, 2 error frame, 3 CAN FD,
4 bit-rate switch, 5 error-state indicator), ``u8 dlc``, ``u8 length``, then ``length`` data
bytes.
"""
from __future__ import annotations

import json
import logging
import math
import os
import queue
import struct
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import can
import zenoh
from can.bus import BusABC, CanProtocol

from ersac_hil.canbus.direct import listener_config
from ersac_hil.zenoh_session import ZenohConfigError, ZenohOptions, open_session, resolve_config
from protocol.can.fastpath import (FLAG_BRS, FLAG_ERROR, FLAG_ESI, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, NOT_DATA,
                                    BurstNotifier, BurstSender, Frame, FramePusher)
from protocol.zenoh.errors import KeySpaceError
from protocol.zenoh.keys import validate_chunk

__all__ = ["ZenohBus", "PushNotifier", "DEFAULT_PREFIX", "low_latency", "encode_frame", "encode_data_frames",
           "decode_frame", "decode_frames", "parse_channel"]

DEFAULT_PREFIX = "can"
#: How long ``shutdown`` waits for a put in progress on another thread (seconds).
SHUTDOWN_WAIT_S = 5.0
#: Samples a busy-polling bus's Zenoh channel holds before Zenoh's receive task waits for its
#: receive thread (the flow control of congestion control ``BLOCK``).
RX_CAPACITY = 1024
_log = logging.getLogger(__name__)
_HEADER = struct.Struct("<IBBB")
_EXTENDED, _REMOTE, _ERROR, _FD, _BRS, _ESI = FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR, FLAG_FD, FLAG_BRS, FLAG_ESI


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
    now = time.time()
    return [_message(frame, now, channel) for frame in _split(payload)]


def _split(payload: bytes) -> list[Frame]:
    """``(arbitration id, flags, dlc, data)`` of every frame of a sample (see
    :func:`decode_frames`, which raises the same ``ValueError``)."""
    out, at, end, header, size = [], 0, len(payload), _HEADER.unpack_from, _HEADER.size
    whole = bytearray(payload)
    while at < end:
        if end - at < size:
            raise ValueError(f"CAN-over-Zenoh sample: {end - at} bytes left, shorter than a frame header")
        arbitration_id, flags, dlc, length = header(whole, at)
        at += size
        if end - at < length:
            raise ValueError(f"CAN-over-Zenoh sample: frame 0x{arbitration_id:X} needs {length} data bytes, "
                             f"{end - at} left")
        out.append((arbitration_id, flags, dlc, whole[at:at + length]))
        at += length
    if not out:
        raise ValueError("CAN-over-Zenoh sample without a frame")
    return out


def _message(frame: Frame, timestamp: float, channel: str | None) -> can.Message:
    arbitration_id, flags, dlc, data = frame
    return can.Message(timestamp=timestamp, arbitration_id=arbitration_id,
                       is_extended_id=bool(flags & _EXTENDED), is_remote_frame=bool(flags & _REMOTE),
                       is_error_frame=bool(flags & _ERROR), is_fd=bool(flags & _FD),
                       bitrate_switch=bool(flags & _BRS), error_state_indicator=bool(flags & _ESI),
                       dlc=dlc, data=data, channel=channel, is_rx=True, check=False)


def encode_data_frames(frames: Sequence[tuple[int, bytes]]) -> bytes:
    """The wire form of standard-id data frames ``(arbitration id, data)`` sent as one
    sample: what :func:`encode_frame` gives the equivalent ``can.Message`` objects."""
    pack = _HEADER.pack
    return b"".join([pack(arbitration_id, 0, len(data), len(data)) + data for arbitration_id, data in frames])


def decode_frame(payload: bytes, channel: str | None = None) -> can.Message:
    """The single frame of a sample (see :func:`decode_frames`)."""
    frames = decode_frames(payload, channel)
    if len(frames) != 1:
        raise ValueError(f"CAN-over-Zenoh sample with {len(frames)} frames, expected one")
    return frames[0]


def _endpoints(value: str | Sequence[str] | None) -> tuple[str, ...]:
    """Endpoints given as a comma-separated string (python-can configuration) or a sequence."""
    if value is None:
        return ()
    return tuple(e for e in value.split(",") if e) if isinstance(value, str) else tuple(value)


def parse_channel(channel: Any, connect: str | Sequence[str] | None = None, *,
                  need_endpoint: bool = True) -> tuple[str, tuple[str, ...]]:
    """``(channel name, endpoints)`` from ``"name"`` plus ``connect``, or ``"name@ep[,ep...]"``;
    no endpoint only without ``need_endpoint`` (a Zenoh config file gives them).

    Raises:
        ValueError: a bad channel name, or no endpoint where one is needed.
    """
    if not isinstance(channel, str) or not channel:
        raise ValueError(f"zenoh CAN channel must be a non-empty string, got {channel!r}")
    name, _, inline = channel.partition("@")
    endpoints = _endpoints(inline) + _endpoints(connect)
    try:
        validate_chunk(name, "zenoh CAN channel name")
    except KeySpaceError as exc:
        raise ValueError(str(exc)) from None
    if need_endpoint and not endpoints:
        raise ValueError(f"zenoh CAN channel {name!r}: no Zenoh endpoint (channel 'name@tcp/HOST:PORT', "
                         "connect=... or zenoh_config=FILE)")
    return name, endpoints


def low_latency(config: zenoh.Config) -> zenoh.Config:
    """``config`` asking for Zenoh's low-latency unicast transport (QoS off: the two exclude
    each other); returns it."""
    config.insert_json5("transport/unicast/lowlatency", "true")
    config.insert_json5("transport/unicast/qos/enabled", "false")
    return config


def _seconds(value: float | str, name: str) -> float:
    """A non-negative duration keyword argument in seconds, also as a string (python-can's
    configuration)."""
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"zenoh CAN bus: {name} must be a number of seconds, got {value!r}") from None
    if not (math.isfinite(seconds) and seconds >= 0.0):
        raise ValueError(f"zenoh CAN bus: {name} must be finite and >= 0 seconds, got {value!r}")
    return seconds


def _flag(value: bool | str, name: str) -> bool:
    """A boolean keyword argument, also as python-can's configuration gives it (a string)."""
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("1", "true", "yes", "on"):
        return True
    if text in ("0", "false", "no", "off", ""):
        return False
    raise ValueError(f"zenoh CAN bus: {name} must be true or false, got {value!r}")


class ZenohBus(BusABC, BurstSender, FramePusher):
    """A python-can bus whose frames travel as Zenoh samples (see the module doc).

    Args:
        channel: ``"name"`` (with ``connect``) or ``"name@tcp/HOST:PORT[,...]"``.
        connect: Zenoh endpoints to connect to (string, comma-separated, or sequence).
        prefix: key prefix of the channel's key (default ``can``).
        receive_own_messages: also receive the frames this bus sends.
        mode: Zenoh session mode, ``client`` (default, through the router) or ``peer``.
        connect_timeout: s to keep trying the endpoints when opening.
        zenoh_config: a Zenoh json5 configuration file (TLS certificates of a role...); its
            endpoints are used when the channel and ``connect`` give none.
        insecure: allow plain endpoints off loopback (``--insecure``).
        listen: endpoints this bus listens on for the others of a direct link (string,
            comma-separated, or sequence; ``ersac_hil.canbus.direct``); it then connects only
            to the channel's own endpoints.
        lowlatency: Zenoh's low-latency transport on this bus's session (see the module doc;
            ``True``/``False`` or python-can configuration's strings).
        busy_poll: seconds the receive thread keeps polling for the next sample after one
            before it blocks (see the module doc; ``0``, the default: Zenoh's callback thread,
            no polling).
        **kwargs: other python-can arguments (``bitrate``, ``can_filters``...); bit rate
            has no meaning here and is ignored.

    Raises:
        can.CanInitializationError: bad channel or endpoints, or no Zenoh session.
    """

    def __init__(self, channel: Any = None, can_filters=None, *, connect: str | Sequence[str] | None = None,  # noqa: ANN001
                 prefix: str = DEFAULT_PREFIX, receive_own_messages: bool = False,
                 mode: str = "client", connect_timeout: float = 10.0, zenoh_config: str | None = None,
                 insecure: bool | str = False, listen: str | Sequence[str] | None = None,
                 lowlatency: bool | str = True, busy_poll: float | str = 0.0, **kwargs: Any) -> None:
        try:
            listen_eps = _endpoints(listen)
            name, endpoints = parse_channel(channel, connect, need_endpoint=not (zenoh_config or listen_eps))
            if mode not in ("client", "peer"):
                raise ValueError(f"zenoh CAN bus mode must be client or peer, got {mode!r}")
            insecure = _flag(insecure, "insecure")
            options = ZenohOptions(endpoints, str(zenoh_config) if zenoh_config else None, insecure)
            if listen_eps:
                config = listener_config(options, listen_eps, connect_timeout_s=float(connect_timeout))
            else:
                config = resolve_config(options, mode=mode, connect_timeout_s=float(connect_timeout))
            if _flag(lowlatency, "lowlatency"):
                low_latency(config)
            self.busy_poll = _seconds(busy_poll, "busy_poll")
            for chunk in str(prefix).split("/"):
                validate_chunk(chunk, "zenoh CAN key prefix")
        except (ValueError, ZenohConfigError, KeySpaceError) as exc:
            raise can.CanInitializationError(str(exc)) from None
        self.key = f"{prefix}/{name}"
        via = ",".join(json.loads(config.get_json("connect/endpoints")) or
                       [f"listening on {','.join(listen_eps)}"])
        self.channel_info = f"CAN over Zenoh on {self.key} via {via}" + (
            f" ({zenoh_config})" if zenoh_config else "")
        self._name = name
        self._rx: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._push: PushNotifier | None = None
        try:
            self._session = open_session(config, insecure=insecure)
        except Exception as exc:  # noqa: BLE001 - ZenohSessionError and whatever zenoh raises
            raise can.CanInitializationError(f"{self.channel_info}: {exc}") from None
        origin = zenoh.Locality.ANY if receive_own_messages else zenoh.Locality.REMOTE
        self._publisher = self._session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.BLOCK, express=False,
            reliability=zenoh.Reliability.RELIABLE)
        self._receiver: threading.Thread | None = None
        if self.busy_poll:
            self._subscriber = self._session.declare_subscriber(
                self.key, zenoh.handlers.FifoChannel(RX_CAPACITY), allowed_origin=origin)
        else:
            self._subscriber = self._session.declare_subscriber(self.key, self._on_sample,
                                                                allowed_origin=origin)
        self._closed = False
        #: held by every put and by shutdown: zenoh's publisher must not be undeclared while
        #: another thread is inside its put (zenoh raises "Already borrowed")
        self._send_lock = threading.Lock()
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD
        if self.busy_poll:
            self._receiver = threading.Thread(target=self._receive, args=(self._subscriber.handler,),
                                              name=f"zenoh-can-rx {self.key}", daemon=True)
            self._receiver.start()

    def _receive(self, handler: zenoh.handlers.Handler) -> None:
        """The receive thread of a busy-polling bus: every sample to :meth:`_on_sample`, in
        order; after one, polls for ``busy_poll`` s before it blocks (see the module doc).
        Ends when the subscriber is undeclared (``shutdown``)."""
        try_recv, recv, on_sample = handler.try_recv, handler.recv, self._on_sample
        clock, pause, window = time.perf_counter, os.sched_yield, self.busy_poll
        hot_until = 0.0
        while True:
            try:
                sample = try_recv()
                if sample is None:
                    if clock() < hot_until:
                        pause()  # the GIL's other threads run meanwhile
                        continue
                    sample = recv()
            except zenoh.ZError:
                return  # the channel is closed: the bus is shut down
            try:
                on_sample(sample)
            except Exception:  # noqa: BLE001 - as Zenoh's callback thread would: log, go on
                _log.exception("%s: receiving a sample failed", self.channel_info)
            hot_until = clock() + window

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            frames = _split(sample.payload.to_bytes())
        except ValueError:
            return  # not frames: nothing a CAN node could receive
        now, push = time.time(), self._push
        if push is None:
            for frame in frames:
                self._rx.put(_message(frame, now, self._name))
        elif self._filters is None:
            push.deliver_frames(frames, now)
        else:
            for frame in push.intercepted(frames, now):
                msg = _message(frame, now, self._name)
                if self._matches_filters(msg):
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

    def send_data_frames(self, frames: Sequence[tuple[int, bytes]]) -> None:
        """Send standard-id data frames ``(arbitration id, data)`` in this order as one burst,
        without building ``can.Message`` objects (see the module doc)."""
        if frames:
            self._put(encode_data_frames(frames))

    def send_many(self, msgs: Sequence[can.Message]) -> None:
        """Send ``msgs`` in this order as one burst (one Zenoh sample, see the module doc)."""
        if msgs:
            self._put(b"".join([encode_frame(m) for m in msgs]))

    def _put(self, payload: bytes) -> None:
        with self._send_lock:
            if self._closed:
                raise can.CanOperationError(f"{self.channel_info}: bus is shut down")
            try:
                self._publisher.put(payload)
            except zenoh.ZError as exc:
                raise can.CanOperationError(f"{self.channel_info}: {exc}") from exc

    def shutdown(self) -> None:
        # a put in progress on another thread ends first; one blocked on a dead link (congestion
        # control BLOCK) does not hold the shutdown for longer than SHUTDOWN_WAIT_S
        acquired = self._send_lock.acquire(timeout=SHUTDOWN_WAIT_S)
        try:
            if self._closed:
                return
            self._closed = True
        finally:
            if acquired:
                self._send_lock.release()
        super().shutdown()
        for entity in (self._subscriber, self._publisher):
            try:
                entity.undeclare()
            except (zenoh.ZError, RuntimeError):  # RuntimeError: still in a blocked put; closing the session ends it
                pass
        self._session.close()
        receiver = self._receiver
        if receiver is not None and receiver is not threading.current_thread():
            receiver.join(SHUTDOWN_WAIT_S)  # its channel is closed: it returns at once


class PushNotifier(BurstNotifier):
    """The ``can.Notifier`` interface canopen uses (``add_listener``, ``remove_listener``,
    ``stop``, ``exception``) for frames pushed by a :class:`ZenohBus` (see the module doc)."""

    def __init__(self, bus: ZenohBus, listeners: list) -> None:  # noqa: ANN001
        self.bus = bus
        self.listeners = listeners
        self.exception: Exception | None = None
        self._stopped = False
        self._take: Callable[[list[Frame], float], list[Frame]] | None = None

    def intercept(self, take: Callable[[list[Frame], float], list[Frame]] | None) -> None:
        """From now on hand every sample's frames to ``take(frames, timestamp)`` first, on the
        receive thread, in one call: it consumes the frames it handles and returns the others
        in order (a new list or ``frames`` itself), which the listeners then get as usual
        (``can_filters`` apply to them only). ``None`` removes it. Its exception is kept like a
        listener's (``exception``), and nothing more is delivered."""
        self._take = take

    def intercepted(self, frames: list[Frame], timestamp: float) -> list[Frame]:
        """What the interceptor leaves of ``frames`` for the listeners (all without one; none
        once stopped or failed)."""
        if self._stopped or self.exception is not None:
            return []
        take = self._take
        if take is None:
            return frames
        try:
            return take(frames, timestamp)
        except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
            self._failed(exc)
            return []

    def deliver(self, msg: can.Message) -> None:
        if self._stopped or self.exception is not None:
            return
        try:
            for listener in self.listeners:
                callback = getattr(listener, "on_message_received", listener)
                callback(msg)
        except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
            self._failed(exc)

    def deliver_frames(self, frames: list[Frame], timestamp: float) -> None:
        """The frames of one sample, in order, what the interceptor leaves of them: ``on_frame``
        listeners get data frames as ``(can_id, data, timestamp)``, the others a
        ``can.Message`` (one per frame, shared)."""
        frames = self.intercepted(frames, timestamp)
        if not frames:
            return
        channel = self.bus._name
        # each listener's entry point, looked up once per sample: (on_frame, None) or (None, callback)
        targets = [(on_frame, None) if on_frame is not None else
                   (None, getattr(listener, "on_message_received", listener))
                   for listener in self.listeners for on_frame in (getattr(listener, "on_frame", None),)]
        for frame in frames:
            if self._stopped or self.exception is not None:
                return
            msg = None
            data_frame = not frame[1] & NOT_DATA
            try:
                for on_frame, callback in targets:
                    if on_frame is not None:
                        if data_frame:
                            on_frame(frame[0], frame[3], timestamp)
                        continue
                    if msg is None:
                        msg = _message(frame, timestamp, channel)
                    callback(msg)
            except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
                self._failed(exc)

    def _failed(self, exc: Exception) -> None:
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
