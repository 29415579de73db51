"""What the project's own CAN transports share: the wire form of frames, bursts and their
push delivery.

CAN over Zenoh (``ersac_hil.canbus.zenoh_bus``) and CAN over a Unix socket
(``ersac_hil.canbus.ipc``) carry frames the same way: one message of the transport holds one
or more frames back to back, each (little-endian) ``u32 arbitration_id``, ``u8 flags`` (bit 0
extended id, 1 remote, 2 error frame, 3 CAN FD, 4 bit-rate switch, 5 error-state indicator),
``u8 dlc``, ``u8 length``, then ``length`` data bytes. Receivers see the frames one by one, in
order, as if sent singly.

:class:`PushingBus` is their common receive side: every received message's frames go to the
``recv()`` queue or, once :meth:`PushingBus.push_notifier` is attached, to its
:class:`PushNotifier`'s listeners on the bus's own receive thread (``on_frame(can_id, data,
timestamp)`` listeners without a ``can.Message`` built for them; an interceptor takes a whole
message's frames first; ``can_filters`` then apply per message).
"""
from __future__ import annotations

import math
import queue
import struct
import time
from collections.abc import Callable, Sequence

import can

from protocol.can.fastpath import (FLAG_BRS, FLAG_ERROR, FLAG_ESI, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, NOT_DATA,
                                    BurstNotifier, BurstSender, Frame)

__all__ = ["PushingBus", "PushNotifier", "MessageSender", "encode_frame", "encode_data_frames", "decode_frame", "decode_frames",
           "split_frames", "seconds_arg", "flag_arg"]

_HEADER = struct.Struct("<IBBB")
_EXTENDED, _REMOTE, _ERROR, _FD, _BRS, _ESI = FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR, FLAG_FD, FLAG_BRS, FLAG_ESI


def encode_frame(msg: can.Message) -> bytes:
    """The wire form of ``msg`` (see the module doc); a message carries one or more."""
    flags = ((_EXTENDED if msg.is_extended_id else 0) | (_REMOTE if msg.is_remote_frame else 0)
             | (_ERROR if msg.is_error_frame else 0) | (_FD if msg.is_fd else 0)
             | (_BRS if msg.bitrate_switch else 0) | (_ESI if msg.error_state_indicator else 0))
    data = bytes(msg.data)
    return _HEADER.pack(msg.arbitration_id, flags, msg.dlc, len(data)) + data


def decode_frames(payload: bytes, channel: str | None = None) -> list[can.Message]:
    """Every frame of a message, as received ``can.Message`` objects timestamped now.

    Raises:
        ValueError: a payload that does not split into whole frames.
    """
    now = time.time()
    return [message_of(frame, now, channel) for frame in split_frames(payload)]


def split_frames(payload: bytes) -> list[Frame]:
    """``(arbitration id, flags, dlc, data)`` of every frame of a message (see
    :func:`decode_frames`, which raises the same ``ValueError``)."""
    out, at, end, header, size = [], 0, len(payload), _HEADER.unpack_from, _HEADER.size
    whole = bytearray(payload)
    while at < end:
        if end - at < size:
            raise ValueError(f"CAN message: {end - at} bytes left, shorter than a frame header")
        arbitration_id, flags, dlc, length = header(whole, at)
        at += size
        if end - at < length:
            raise ValueError(f"CAN message: frame 0x{arbitration_id:X} needs {length} data bytes, "
                             f"{end - at} left")
        out.append((arbitration_id, flags, dlc, whole[at:at + length]))
        at += length
    if not out:
        raise ValueError("CAN message without a frame")
    return out


def message_of(frame: Frame, timestamp: float, channel: str | None) -> can.Message:
    arbitration_id, flags, dlc, data = frame
    return can.Message(timestamp=timestamp, arbitration_id=arbitration_id,
                       is_extended_id=bool(flags & _EXTENDED), is_remote_frame=bool(flags & _REMOTE),
                       is_error_frame=bool(flags & _ERROR), is_fd=bool(flags & _FD),
                       bitrate_switch=bool(flags & _BRS), error_state_indicator=bool(flags & _ESI),
                       dlc=dlc, data=data, channel=channel, is_rx=True, check=False)


def encode_data_frames(frames: Sequence[tuple[int, bytes]]) -> bytes:
    """The wire form of standard-id data frames ``(arbitration id, data)`` sent as one
    message: what :func:`encode_frame` gives the equivalent ``can.Message`` objects."""
    pack = _HEADER.pack
    return b"".join([pack(arbitration_id, 0, len(data), len(data)) + data for arbitration_id, data in frames])


def decode_frame(payload: bytes, channel: str | None = None) -> can.Message:
    """The single frame of a message (see :func:`decode_frames`)."""
    frames = decode_frames(payload, channel)
    if len(frames) != 1:
        raise ValueError(f"CAN message with {len(frames)} frames, expected one")
    return frames[0]



def seconds_arg(value: float | str, name: str) -> float:
    """A non-negative duration keyword argument in seconds, also as a string (python-can's
    configuration)."""
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"CAN bus: {name} must be a number of seconds, got {value!r}") from None
    if not (math.isfinite(seconds) and seconds >= 0.0):
        raise ValueError(f"CAN bus: {name} must be finite and >= 0 seconds, got {value!r}")
    return seconds


def flag_arg(value: bool | str, name: str) -> bool:
    """A boolean keyword argument, also as python-can's configuration gives it (a string)."""
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("1", "true", "yes", "on"):
        return True
    if text in ("0", "false", "no", "off", ""):
        return False
    raise ValueError(f"CAN bus: {name} must be true or false, got {value!r}")


class MessageSender(BurstSender):
    """The send side of a bus whose transport carries messages of this module's wire form: the
    subclass's ``_put(payload)`` sends one message."""

    def _put(self, payload: bytes) -> None:
        raise NotImplementedError

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._put(encode_frame(msg))

    def send_data_frames(self, frames: Sequence[tuple[int, bytes]]) -> None:
        """Send standard-id data frames ``(arbitration id, data)`` in this order as one burst
        (one message), without building ``can.Message`` objects."""
        if frames:
            self._put(encode_data_frames(frames))

    def send_many(self, msgs: Sequence[can.Message]) -> None:
        """Send ``msgs`` in this order as one burst (one message)."""
        if msgs:
            self._put(b"".join([encode_frame(m) for m in msgs]))


class PushingBus(can.BusABC):
    """The receive side of a bus that gets its frames as messages of :func:`split_frames`'s
    form (see the module doc); the subclass sets ``_name`` (the channel name of received
    ``can.Message`` objects) and calls :meth:`_deliver` for each message, on its receive
    thread."""

    _name: str | None = None
    _push: "PushNotifier | None" = None

    def _start_receiving(self) -> None:
        """Call before the first :meth:`_deliver`."""
        self._rx: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._push = None

    def _deliver(self, payload: bytes) -> None:
        """One received message: its frames to the push listeners or the ``recv()`` queue;
        a payload that is not whole frames is dropped (nothing a CAN node could receive)."""
        try:
            frames = split_frames(payload)
        except ValueError:
            return
        now, push = time.time(), self._push
        if push is None:
            for frame in frames:
                self._rx.put(message_of(frame, now, self._name))
        elif self._filters is None:
            push.deliver_frames(frames, now)
        else:
            for frame in push.intercepted(frames, now):
                msg = message_of(frame, now, self._name)
                if self._matches_filters(msg):
                    push.deliver(msg)

    def push_notifier(self, listeners: list) -> "PushNotifier":  # noqa: ANN001
        """Deliver every received frame to ``listeners`` (``can.Listener`` or callables) on
        the bus's receive thread from now on, instead of queueing it for ``recv()``. Stop it
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


class PushNotifier(BurstNotifier):
    """The ``can.Notifier`` interface canopen uses (``add_listener``, ``remove_listener``,
    ``stop``, ``exception``) for frames pushed by a :class:`PushingBus` (see the module doc)."""

    def __init__(self, bus: PushingBus, listeners: list) -> None:  # noqa: ANN001
        self.bus = bus
        self.listeners = listeners
        self.exception: Exception | None = None
        self._stopped = False
        self._take: Callable[[list[Frame], float], list[Frame]] | None = None

    def intercept(self, take: Callable[[list[Frame], float], list[Frame]] | None) -> None:
        """From now on hand every message's frames to ``take(frames, timestamp)`` first, on the
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
            self.fail(exc)
            return []

    def deliver(self, msg: can.Message) -> None:
        if self._stopped or self.exception is not None:
            return
        try:
            for listener in self.listeners:
                callback = getattr(listener, "on_message_received", listener)
                callback(msg)
        except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
            self.fail(exc)

    def deliver_frames(self, frames: list[Frame], timestamp: float) -> None:
        """The frames of one message, in order, what the interceptor leaves of them: ``on_frame``
        listeners get data frames as ``(can_id, data, timestamp)``, the others a
        ``can.Message`` (one per frame, shared)."""
        frames = self.intercepted(frames, timestamp)
        if not frames:
            return
        channel = self.bus._name
        # each listener's entry point, looked up once per message: (on_frame, None) or (None, callback)
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
                        msg = message_of(frame, timestamp, channel)
                    callback(msg)
            except Exception as exc:  # noqa: BLE001 - kept for the owner, like can.Notifier
                self.fail(exc)

    def fail(self, exc: Exception) -> None:
        """Keep ``exc`` (nothing more is delivered) and tell the listeners that have an
        ``on_error`` (as ``can.Notifier`` does: one that does not implement it is skipped)."""
        self.exception = exc
        for listener in self.listeners:
            on_error = getattr(listener, "on_error", None)
            if on_error is not None:
                try:
                    on_error(exc)
                except NotImplementedError:  # can.Listener's default
                    pass

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
