"""The synchronous TPDOs of the SYNC in flight: kept as they arrive, waited for by the cycle.

    collector = TpdoCollector({cob_id: size, ...})
    network.subscribe(cob_id, collector.handler(cob_id))   # frame by frame, for every COB-ID
    notifier.intercept(collector.take)                     # or a whole burst at once (CAN over Zenoh)
    collector.expect()                                     # before each SYNC goes out
    frames, missing = collector.wait(deadline)             # data of each frame by COB-ID

Frames arrive on the bus's receive thread, one by one through canopen (``handler``) or a
Zenoh sample's burst in one call (``take``: one lock per burst, the TPDOs consumed, the other
frames left for canopen). The frame that completes the set wakes the waiting cycle by
releasing a plain lock (no ``threading.Condition``: its
Python-level waiter bookkeeping cost more than the rest of a TPDO's handling). Each frame's
data is kept whole, unpacked by the caller (``telemetry.TelemetryDecoder``); a late frame (after
a timeout) is ignored.

A faulty node on the bus is a bus fault, never data: a TPDO whose length is not its map's (CiA
301's PDO length errors, EMCY 0x8210/0x8220 on a device), or a second copy of a TPDO in one
cycle (a second producer of that COB-ID, or a second SYNC) is not taken and is recorded
(:meth:`TpdoCollector.fault`; the bus layer records what it sees too with :meth:`note`: a
foreign SYNC, error frames...). The first fault recorded is kept until :meth:`fault` takes it.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping

from protocol.can.fastpath import ERROR_FRAME, NOT_DATA, Frame

__all__ = ["TpdoCollector", "foreign_frame"]

_NONE_MISSING: frozenset[int] = frozenset()


def foreign_frame(cob_id: int, error: bool = False, remote: bool = False) -> str:
    """The bus fault of a frame that is not data of the robot's nodes: an error or remote
    frame, or a data frame of a COB-ID none of the robot's nodes sends."""
    if error or remote:
        return f"{'error' if error else 'remote'} frame 0x{cob_id:03X} on the bus"
    return (f"a frame of 0x{cob_id:03X}, which no node of the robot sends (a foreign SYNC/NMT, a second "
            "producer of the agent's frames, or a babbling node)")


class TpdoCollector:
    """Args:
        sizes: per COB-ID of a synchronous TPDO, the size of its map in bytes.
        known: the COB-IDs the robot's nodes send; in a burst (``take``) any other frame is
            a fault (``None``: not checked; frame by frame, the bus layer checks).
    """

    def __init__(self, sizes: Mapping[int, int], known: frozenset[int] | None = None) -> None:
        self._sizes = dict(sizes)
        self._known = known
        self._lock = threading.Lock()
        self._arrived = threading.Lock()
        self._arrived.acquire()  # held while a set is incomplete; released by its last frame
        self._pending: set[int] = set()
        self._frames: dict[int, bytes | bytearray] = {}
        self._fault: str | None = None

    def note(self, fault: str) -> None:
        """Record a bus fault (the first one is kept until :meth:`fault` takes it)."""
        if self._fault is None:
            self._fault = fault

    def fault(self) -> str | None:
        """The first bus fault recorded since the last call (``None``: none), taken."""
        fault, self._fault = self._fault, None
        return fault

    def _odd(self, cob_id: int, n: int) -> bool:
        """Record what is wrong with a frame of TPDO ``cob_id`` of ``n`` bytes that is not
        taken (called under the lock); ``True`` if it is a fault."""
        size = self._sizes[cob_id]
        if n != size:
            self.note(f"TPDO 0x{cob_id:03X} of {n} bytes, its map has {size}")
        elif cob_id in self._frames and cob_id not in self._pending:
            self.note(f"TPDO 0x{cob_id:03X} twice in one cycle (a second producer, or a second SYNC)")
        else:
            return False
        return True

    def handler(self, cob_id: int) -> Callable[[int, bytearray, float], None]:
        """The ``(can_id, data, timestamp)`` callback of ``cob_id`` (canopen's subscriber
        signature)."""
        size = self._sizes[cob_id]
        lock, pending, frames, arrived = self._lock, self._pending, self._frames, self._arrived

        def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
            with lock:
                if cob_id not in pending or len(data) != size:
                    self._odd(cob_id, len(data))
                    return
                frames[cob_id] = data
                pending.discard(cob_id)
                if not pending:
                    arrived.release()
        return on_frame

    def take(self, frames: list[Frame], timestamp: float) -> list[Frame]:
        """A burst interceptor (``protocol.can.fastpath.BurstNotifier.intercept``): keeps
        the expected data frames of ``frames`` as ``handler`` would, one after the other, and
        returns the others in order."""
        sizes, pending, kept = self._sizes, self._pending, self._frames
        rest: list[Frame] = []
        with self._lock:
            waiting = bool(pending)
            for frame in frames:
                cob_id, flags, _, data = frame
                if cob_id in sizes and not flags & NOT_DATA:
                    if cob_id in pending and len(data) == sizes[cob_id]:
                        kept[cob_id] = data
                        pending.discard(cob_id)
                        continue
                    if self._odd(cob_id, len(data)):
                        continue
                elif flags & NOT_DATA or (self._known is not None and cob_id not in self._known):
                    self.note(foreign_frame(cob_id, bool(flags & ERROR_FRAME), bool(flags & NOT_DATA)))
                    continue
                rest.append(frame)
            if waiting and not pending:
                self._arrived.release()
        return rest

    def expect(self) -> None:
        """A SYNC is about to go out: every TPDO pending, none received."""
        with self._lock:
            self._pending.update(self._sizes)
            self._frames.clear()

    def wait(self, deadline: float, give_up: bool = True
             ) -> tuple[Mapping[int, bytes | bytearray], frozenset[int] | set[int]]:
        """Until every expected TPDO is in or ``time.perf_counter()`` passes ``deadline``:
        the data of each frame by COB-ID (valid until the next ``expect``) and the COB-IDs
        still missing (none pending afterwards, unless ``give_up`` is false: then the missing
        ones stay expected and a later ``wait`` may still get them)."""
        if not self._sizes:
            return {}, _NONE_MISSING
        if self._arrived.acquire(timeout=max(0.0, deadline - time.perf_counter())):
            return self._frames, _NONE_MISSING  # the set is complete: nothing writes until expect()
        with self._lock:
            if not self._pending:  # completed between the timeout and the lock (released under it)
                self._arrived.acquire(blocking=False)
                return self._frames, _NONE_MISSING
            missing = set(self._pending)
            if give_up:
                self._pending.clear()
            return self._frames, missing
