"""CAN traces per episode (``ersac-hil agent --record-can DIR``).

A tap bus on the agent's channel (its own python-can bus, like ``candump``: it sees every
frame on the bus, the agent's and the controllers') feeds a python-can log writer while an
episode runs: ``DIR/<episode_id>.blf`` (Vector BLF, default) or ``.asc``, readable by
``python -m can.player``, ``can.LogReader`` and the common CAN tools. Between episodes frames
are dropped. The file name goes back to the learner in ``EpisodeResult.trace``.

An episode's trace holds the frames whose timestamps fall between :meth:`CanRecorder.begin`
and :meth:`CanRecorder.end`; ``end`` waits until the tap has caught up with the bus (at most
:data:`CATCH_UP_S`; normally at once), so the trace is complete when the agent replies, also
on a loaded machine where the tap thread lags behind the control loop.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from pathlib import Path

import can

from protocol.can.busconfig import BusConfig, open_bus

__all__ = ["FORMATS", "CanRecorder"]

log = logging.getLogger(__name__)

#: Log formats (file suffixes) the recorder writes.
FORMATS: tuple[str, ...] = ("blf", "asc")
#: Longest wait in :meth:`CanRecorder.end` for the tap to catch up with the bus.
CATCH_UP_S = 30.0


class CanRecorder:
    """``start()``, then per episode ``begin(episode_id)`` ... ``end() -> file name``; ``stop()``.

    Args:
        bus: the agent's bus configuration (the tap opens its own bus on the same channel).
        directory: where the traces go (created).
        fmt: ``"blf"`` or ``"asc"``.
    """

    def __init__(self, bus: BusConfig, directory: str | Path, fmt: str = "blf") -> None:
        if fmt not in FORMATS:
            raise ValueError(f"CAN trace format {fmt!r} is not one of {list(FORMATS)}")
        self.directory = Path(directory)
        self.fmt = fmt
        self._config = bus
        self._bus: can.BusABC | None = None
        self._writer: can.Listener | None = None
        self._name = ""
        self._window = (math.inf, math.inf)  # (begin, end) wall-clock times of the trace
        self._seen = 0.0  # the tap has handled everything up to this time
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames = 0

    def start(self) -> CanRecorder:
        self.directory.mkdir(parents=True, exist_ok=True)
        self._bus = open_bus(self._config)
        self._thread = threading.Thread(target=self._run, name="can-trace", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        bus = self._bus
        while not self._stop.is_set():
            try:
                msg = bus.recv(0.05)
            except (can.CanError, OSError, ValueError) as exc:  # the bus went away
                log.warning("CAN trace tap stopped: %s", exc)
                return
            now = time.time()
            with self._lock:
                if msg is None:  # the queue is empty: caught up
                    self._seen = now
                else:
                    stamp = msg.timestamp if abs(msg.timestamp - now) < 3600 else now
                    begin, end = self._window
                    if self._writer is not None and begin <= stamp <= end:
                        # one bus per trace; python-can's writers would take the channel name's
                        # trailing digits as its number (BLF: 16 bits, 'trace-1a970355' overflows)
                        msg.channel = None
                        self._writer.on_message_received(msg)
                        self.frames += 1
                    self._seen = max(self._seen, stamp)
                self._lock.notify_all()

    def begin(self, episode_id: str) -> None:
        """Start writing ``<episode_id>.<fmt>`` (an unfinished previous trace is closed)."""
        self.end()
        name = f"{episode_id}.{self.fmt}"
        writer = can.Logger(str(self.directory / name))
        with self._lock:
            self._writer, self._name, self._window = writer, name, (time.time(), math.inf)

    def end(self) -> str:
        """Close the episode's trace; returns its file name (``""`` if none was open)."""
        with self._lock:
            if self._writer is None:
                return ""
            end = time.time()
            self._window = (self._window[0], end)
            if not self._lock.wait_for(lambda: self._seen >= end or self._stop.is_set(), timeout=CATCH_UP_S):
                log.warning("CAN trace %s may miss the last frames: the tap lags %.1f s behind",
                            self._name, end - self._seen)
            writer, name, self._writer, self._name = self._writer, self._name, None, ""
        writer.stop()
        return name

    def stop(self) -> None:
        self.end()
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        if self._thread is not None:
            self._thread.join(2.0)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
