"""The synchronous TPDOs of the SYNC in flight: unpacked as they arrive, waited for by the cycle.

    collector = TpdoCollector({cob_id: struct, ...})
    network.subscribe(cob_id, collector.handler(cob_id))   # for every COB-ID, once
    collector.expect()                                     # before each SYNC goes out
    frames, missing = collector.wait(deadline)             # unpacked fields by COB-ID

The handlers run on the bus's receive thread. The frame that completes the set wakes the
waiting cycle by releasing a plain lock (no ``threading.Condition``: its Python-level waiter
bookkeeping cost more than the rest of a TPDO's handling). A frame that is not expected (late,
after a timeout, or a second copy) is ignored.
"""
from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Mapping

__all__ = ["TpdoCollector"]


class TpdoCollector:
    """Args:
        layouts: per COB-ID of a synchronous TPDO, the struct of its fields.
    """

    def __init__(self, layouts: Mapping[int, struct.Struct]) -> None:
        self._layouts = dict(layouts)
        self._lock = threading.Lock()
        self._arrived = threading.Lock()
        self._arrived.acquire()  # held while a set is incomplete; released by its last frame
        self._pending: set[int] = set()
        self._frames: dict[int, tuple[int, ...]] = {}

    def handler(self, cob_id: int) -> Callable[[int, bytearray, float], None]:
        """The ``(can_id, data, timestamp)`` callback of ``cob_id`` (canopen's subscriber
        signature); frames shorter than the map are ignored."""
        layout = self._layouts[cob_id]
        unpack, size = layout.unpack_from, layout.size
        lock, pending, frames, arrived = self._lock, self._pending, self._frames, self._arrived

        def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            with lock:
                if cob_id not in pending:
                    return
                frames[cob_id] = unpack(data)
                pending.discard(cob_id)
                if not pending:
                    arrived.release()
        return on_frame

    def expect(self) -> None:
        """A SYNC is about to go out: every TPDO pending, none received."""
        with self._lock:
            self._pending.update(self._layouts)
            self._frames.clear()

    def wait(self, deadline: float) -> tuple[dict[int, tuple[int, ...]], set[int]]:
        """Until every expected TPDO is in or ``time.perf_counter()`` passes ``deadline``:
        the unpacked fields by COB-ID and the COB-IDs still missing (none pending afterwards)."""
        if not self._layouts:
            return {}, set()
        done = self._arrived.acquire(timeout=max(0.0, deadline - time.perf_counter()))
        with self._lock:
            if not done and not self._pending:  # completed between the timeout and the lock
                self._arrived.acquire(blocking=False)
            missing = set(self._pending)
            self._pending.clear()
            return dict(self._frames), missing
