"""The fast paths a CAN bus may declare beyond python-can's ``BusABC``, and the frame type they
carry. CAN over Zenoh (``ersac_hil.canbus.zenoh_bus.ZenohBus``, through a router or on a direct
link) declares them; a plain python-can bus does not, and gets the ordinary paths.

* :class:`BurstSender`: several frames sent as one message (``send_data_frames`` from
  ``(arbitration id, data)`` pairs, ``send_many`` from ``can.Message`` objects), received one
  by one, in order, as if sent singly.
* :class:`FramePusher`: ``push_notifier(listeners)`` delivers every received frame to the
  listeners on the bus's own receive thread (no ``can.Notifier`` thread); the notifier it
  returns is a :class:`BurstNotifier`.
* :class:`BurstNotifier`: ``intercept(take)`` hands each received message's frames, as
  :data:`Frame` tuples, to ``take(frames, timestamp)`` in one call before the listeners.

Both sides check for them once, with ``isinstance``, when they set their bus up
(``busconfig.open_network``, the agent's TPDO collector), never per frame. Nothing here opens
anything.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

import can

__all__ = ["Frame", "FLAG_EXTENDED", "FLAG_REMOTE", "FLAG_ERROR", "FLAG_FD", "FLAG_BRS", "FLAG_ESI", "NOT_DATA",
           "ERROR_FRAME", "BurstSender", "FramePusher", "BurstNotifier"]

Frame = tuple[int, int, int, bytearray]
"""One received frame as the fast paths handle it: ``(arbitration id, flags, dlc, data)``."""
FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR, FLAG_FD, FLAG_BRS, FLAG_ESI = (1 << i for i in range(6))
"""The bits of a :data:`Frame`'s flags: extended id, remote frame, error frame, CAN FD,
bit-rate switch, error-state indicator (CAN over Zenoh's wire format carries them as they are)."""
NOT_DATA = FLAG_REMOTE | FLAG_ERROR
"""Flags of the frames that carry no data (remote and error frames)."""
ERROR_FRAME = FLAG_ERROR
"""The flag of an error frame."""


class BurstSender(ABC):
    """A bus that sends several frames as one message."""

    @abstractmethod
    def send_data_frames(self, frames: Sequence[tuple[int, bytes]]) -> None:
        """Send standard-id data frames ``(arbitration id, data)`` in this order, as one burst."""

    @abstractmethod
    def send_many(self, msgs: Sequence[can.Message]) -> None:
        """Send ``msgs`` in this order, as one burst."""


class BurstNotifier(ABC):
    """A notifier (the ``can.Notifier`` interface canopen uses) that can take each received
    burst whole."""

    @abstractmethod
    def intercept(self, take: Callable[[list[Frame], float], list[Frame]] | None) -> None:
        """From now on hand every burst's frames to ``take(frames, timestamp)`` first, on the
        receive thread: it consumes the frames it handles and returns the others in order, which
        the listeners then get as usual. ``None`` removes it."""

    @abstractmethod
    def add_listener(self, listener) -> None: ...  # noqa: ANN001

    @abstractmethod
    def remove_listener(self, listener) -> None: ...  # noqa: ANN001

    @abstractmethod
    def stop(self, timeout: float = 5.0) -> None: ...


class FramePusher(ABC):
    """A bus that pushes received frames to listeners on its own receive thread."""

    @abstractmethod
    def push_notifier(self, listeners: list) -> BurstNotifier:  # noqa: ANN001
        """Deliver every received frame to ``listeners`` from now on, instead of queueing it for
        ``recv()``; stop it with the returned notifier's ``stop()``."""
