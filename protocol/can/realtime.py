"""Real-time scheduling of a process on the SYNC loop's path (both sides of the bus).

A real robot's balance loop runs at 200 Hz: a SYNC delayed past the 5 ms period is a missed
deadline. On a loaded Linux machine most of that delay is waiting for a core, so both the
agent (SYNC producer) and a real-time simulator ask for ``SCHED_FIFO`` at the same priority
for every thread of their process - Python's and the transport's own (threads created later
inherit the policy). Where that is not permitted (no CAP_SYS_NICE, RLIMIT_RTPRIO 0, not
Linux) the process keeps normal scheduling and says why.

Both processes also keep Python's cyclic garbage collector off the SYNC path
(:func:`quiet_gc`), in lock-step and real time alike; the agent switches it off for the
SYNC loop of an episode altogether (:func:`gc_paused`).
"""
from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["SYNC_PRIORITY", "GC_YOUNG_THRESHOLD", "request_realtime", "quiet_gc", "gc_paused"]

#: Allocations between two collections of the youngest generation (Python's default is 700).
GC_YOUNG_THRESHOLD = 50_000

#: SCHED_FIFO priority of the SYNC path (1..99; above ordinary RT housekeeping, below the kernel's).
SYNC_PRIORITY = 20


def request_realtime(priority: int = SYNC_PRIORITY) -> str:
    """Put every thread of this process under ``SCHED_FIFO`` at ``priority``.

    Returns a one-line message saying what happened (granted, or why not); never raises for
    a refusal."""
    if not hasattr(os, "sched_setscheduler") or not os.path.isdir("/proc/self/task"):
        return "real-time scheduling unavailable on this platform: normal scheduling"
    param = os.sched_param(priority)
    try:
        tids = []
        for tid in (int(t) for t in os.listdir("/proc/self/task")):
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            except ProcessLookupError:  # the thread ended since the listing: nothing to schedule
                continue
            tids.append(tid)
    except PermissionError:
        return ("SCHED_FIFO not permitted (needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least "
                f"{priority}, e.g. 'ulimit -r {priority}'): normal scheduling, expect late cycles under load")
    except OSError as exc:
        return f"SCHED_FIFO refused ({exc}): normal scheduling"
    return f"SCHED_FIFO priority {priority} on {len(tids)} thread(s); threads started later inherit it"


def quiet_gc(young: int = GC_YOUNG_THRESHOLD) -> None:
    """Keep the cyclic garbage collector from pausing the SYNC path: call once start-up is done.

    A lock-step cycle allocates a few hundred objects (frames, telemetry, commands), so with
    Python's default thresholds the collector ran every few dozen cycles, walking the young
    objects, and every few hundred cycles every object of the process (MuJoCo's model,
    canopen's object dictionaries, numpy...): up to milliseconds inside a cycle. Everything
    start-up made is frozen (``gc.freeze``: it lives as long as the process and is never
    walked again) and the young generation is collected every ``young`` allocations instead
    of 700. Nothing on the SYNC path makes reference cycles; what a rare one holds is freed a
    little later. No effect on any value computed."""
    gc.collect()
    gc.freeze()
    _, older, oldest = gc.get_threshold()
    gc.set_threshold(young, older, oldest)


@contextmanager
def gc_paused() -> Iterator[None]:
    """No cyclic garbage collection inside the block (a SYNC loop of a few thousand cycles);
    the collector as it was afterwards (then a young collection, when its threshold says).
    Even with :func:`quiet_gc`'s threshold a young collection walks tens of thousands of
    objects, a millisecond or more in one period; an episode's loop makes no reference
    cycles worth collecting. Nested or concurrent use on another thread leaves the collector
    off until the last block that found it on ends."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
