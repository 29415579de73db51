"""CAN traces per episode (``ersac-hil agent --record-can DIR``).

A tap bus on the agent's channel (its own python-can bus, like ``candump``: it sees every
frame on the bus, the agent's and the controllers') feeds a python-can log writer while an
episode runs: ``DIR/<episode_id>.blf`` (Vector BLF, default) or ``.asc``, readable by
``python -m can.player``, ``can.LogReader`` and the common CAN tools. Between episodes frames
are dropped. The file name goes back to the learner in ``EpisodeResult.trace``.
"""
from __future__ import annotations

import logging
import threading
from pathlib import Path

import can

from protocol.can.busconfig import BusConfig, open_bus

__all__ = ["FORMATS", "CanRecorder"]

log = logging.getLogger(__name__)

#: Log formats (file suffixes) the recorder writes.
FORMATS: tuple[str, ...] = ("blf", "asc")


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
        self._lock = threading.Lock()
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
            if msg is None:
                continue
            with self._lock:
                if self._writer is not None:
                    self._writer.on_message_received(msg)
                    self.frames += 1

    def begin(self, episode_id: str) -> None:
        """Start writing ``<episode_id>.<fmt>`` (an unfinished previous trace is closed)."""
        name = f"{episode_id}.{self.fmt}"
        writer = can.Logger(str(self.directory / name))
        with self._lock:
            previous, self._writer, self._name = self._writer, writer, name
        if previous is not None:
            previous.stop()

    def end(self) -> str:
        """Close the episode's trace; returns its file name (``""`` if none was open)."""
        with self._lock:
            writer, name, self._writer, self._name = self._writer, self._name, None, ""
        if writer is None:
            return ""
        writer.stop()
        return name

    def stop(self) -> None:
        self.end()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
