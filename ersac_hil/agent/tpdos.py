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
Python-level waiter bookkeeping cost more than the rest of a TPDO's handling). A frame that is
not expected (late, after a timeout, or a second copy) or shorter than its map is ignored;
each frame's data is kept as the first ``size`` bytes of the map, unpacked by the caller
(``telemetry.TelemetryDecoder``).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping

from ersac_hil.canbus.zenoh_bus import NOT_DATA, Frame

__all__ = ["TpdoCollector"]

_NONE_MISSING: frozenset[int] = frozenset()


class TpdoCollector:
    """Args:
        sizes: per COB-ID of a synchronous TPDO, the size of its map in bytes.
    """

    def __init__(self, sizes: Mapping[int, int]) -> None:
        self._sizes = dict(sizes)
        self._lock = threading.Lock()
        self._arrived = threading.Lock()
        self._arrived.acquire()  # held while a set is incomplete; released by its last frame
        self._pending: set[int] = set()
        self._frames: dict[int, bytes | bytearray] = {}

    def handler(self, cob_id: int) -> Callable[[int, bytearray, float], None]:
        """The ``(can_id, data, timestamp)`` callback of ``cob_id`` (canopen's subscriber
        signature)."""
        size = self._sizes[cob_id]
        lock, pending, frames, arrived = self._lock, self._pending, self._frames, self._arrived

        def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
            n = len(data)
            if n < size:
                return
            with lock:
                if cob_id not in pending:
                    return
                frames[cob_id] = data if n == size else data[:size]
                pending.discard(cob_id)
                if not pending:
                    arrived.release()
        return on_frame

    def take(self, frames: list[Frame], timestamp: float) -> list[Frame]:
        """A burst interceptor (``ersac_hil.canbus.zenoh_bus.PushNotifier.intercept``): keeps
        the expected data frames of ``frames`` as ``handler`` would, one after the other, and
        returns the others in order."""
        sizes, pending, kept = self._sizes, self._pending, self._frames
        rest: list[Frame] = []
        with self._lock:
            waiting = bool(pending)
            for frame in frames:
                cob_id, flags, _, data = frame
                if cob_id in pending and not flags & NOT_DATA:
                    size = sizes[cob_id]
                    if len(data) >= size:
                        kept[cob_id] = data if len(data) == size else data[:size]
                        pending.discard(cob_id)
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
