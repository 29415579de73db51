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
Between buses that know of each other: a Zenoh session sends a put only to the subscriptions
it has been told of, and a bus that just opened declares its subscriber asynchronously, so a
frame another bus sends within milliseconds of that opening may miss it (measured: 47 of 100
lost; a ``get`` round trip to the router as a barrier still lost 2 of 200). Hear a frame of
the new bus before talking to it - a CANopen master waits for the nodes' heartbeats or
boot-up, as the agent does (``AgentBus.wait_for_nodes``): after that 0 of 200 were lost.
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

Wire format of one sample: one or more frames back to back, as ``ersac_hil.canbus.frames``
gives them (the same as CAN over a Unix socket's messages, ``ersac_hil.canbus.ipc``).
"""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import can
import zenoh
from can.bus import CanProtocol

from ersac_hil.canbus.direct import listener_config
from ersac_hil.canbus.frames import (MessageSender, PushingBus, PushNotifier, decode_frame, decode_frames,
                                     encode_data_frames, encode_frame)
from ersac_hil.canbus.frames import flag_arg as _flag
from ersac_hil.canbus.frames import seconds_arg as _seconds
from ersac_hil.zenoh_session import ZenohConfigError, ZenohOptions, open_session, resolve_config
from protocol.can.fastpath import NOT_DATA, FramePusher
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



class ZenohBus(MessageSender, PushingBus, FramePusher):
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
        self._start_receiving()
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
        self._deliver(sample.payload.to_bytes())

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
