"""Real-time scheduling of a process on the SYNC loop's path (both sides of the bus).

A real robot's balance loop runs at 200 Hz: a SYNC delayed past the 5 ms period is a missed
deadline. On a loaded Linux machine most of that delay is waiting for a core, so both the
agent (SYNC producer) and a real-time simulator ask for ``SCHED_FIFO`` at the same priority
for every thread of their process - Python's and the transport's own (threads created later
inherit the policy). Where that is not permitted (no CAP_SYS_NICE, RLIMIT_RTPRIO 0, not
Linux) the process keeps normal scheduling and says why.

Idle cores wake slowly: a core halted in a deep idle state, or a virtual CPU whose hypervisor
descheduled it at its HLT, takes tens of microseconds to milliseconds to run the thread a
frame woke. In real time both processes hold the kernel's PM QoS request
``/dev/cpu_dma_latency`` at 0 us (as ``cyclictest`` does; no deep idle states while they run).
A virtual machine without a cpuidle driver ignores it; there :class:`KeepAwake` (``agent
--keep-awake``) keeps every core busy with spinning ``SCHED_IDLE`` children that any other
thread preempts at once. Measured on this project's 2-core VM, board profile, 200 Hz, ten
minutes idle: SYNC latency p99 (median episode) 2.48 / 2.98 ms without them vs 1.65 / 1.77 ms
with them, missed periods 0.43 % vs 0.07 % (docs/performance.md).

Both processes also keep Python's cyclic garbage collector off the SYNC path
(:func:`quiet_gc`), in lock-step and real time alike; the agent switches it off for the
SYNC loop of an episode altogether (:func:`gc_paused`).
"""
from __future__ import annotations

import gc
import os
import signal
import struct
import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["SYNC_PRIORITY", "GC_YOUNG_THRESHOLD", "PM_QOS_DEVICE", "request_realtime", "hold_wakeup_latency",
           "KeepAwake", "quiet_gc", "gc_paused"]

#: The kernel's CPU wake-up latency request (PM QoS): held open, an int32 of microseconds.
PM_QOS_DEVICE = "/dev/cpu_dma_latency"
_held_qos: list[int] = []  # file descriptors held for the life of the process

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
    return (f"SCHED_FIFO priority {priority} on {len(tids)} thread(s); threads started later inherit it; "
            f"{hold_wakeup_latency()}")


def hold_wakeup_latency(device: str = PM_QOS_DEVICE) -> str:
    """Ask the kernel to keep every core out of idle states slower than 0 us to leave, for as
    long as this process lives (the request ends when its file descriptor closes, at exit).

    Returns a one-line message saying what happened; never raises for a refusal."""
    if _held_qos:
        return "CPU wake-up latency held at 0 us (PM QoS)"
    try:
        fd = os.open(device, os.O_WRONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return f"no {device}: idle states as the kernel chooses"
    except PermissionError:
        return f"{device} not writable (root, or a udev rule granting it): idle states as the kernel chooses"
    except OSError as exc:
        return f"{device} refused ({exc}): idle states as the kernel chooses"
    try:
        os.write(fd, struct.pack("=i", 0))
    except OSError as exc:
        os.close(fd)
        return f"{device} refused ({exc}): idle states as the kernel chooses"
    _held_qos.append(fd)
    return "CPU wake-up latency held at 0 us (PM QoS)"


# a spinning child: dies with its parent (PR_SET_PDEATHSIG), ignores the terminal's Ctrl-C (the
# parent stops it), and does nothing but keep its core out of the idle loop
_SPIN = """
import ctypes, os, signal, sys
ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
signal.signal(signal.SIGINT, signal.SIG_IGN)
if os.getppid() != int(sys.argv[1]):
    sys.exit(0)
while True:
    pass
"""


class KeepAwake:
    """One spinning child per core this process may use, under ``SCHED_IDLE`` (it runs only
    when a core would otherwise idle; every other thread preempts it at once), so no core
    halts between two SYNC periods. For virtual machines and kernels where the PM QoS request
    of :func:`hold_wakeup_latency` cannot keep the cores awake; it spends the idle time of
    every core, so it is opt-in (``agent --keep-awake``).

    The children die with this process (``PR_SET_PDEATHSIG``) and on :meth:`close`."""

    def __init__(self, cores: int | None = None) -> None:
        if cores is None:
            cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        if cores < 1:
            raise ValueError(f"KeepAwake needs at least one core, got {cores}")
        self.cores = cores
        self._pids: list[int] = []

    @property
    def pids(self) -> tuple[int, ...]:
        """The running children's process ids."""
        return tuple(self._pids)

    def start(self) -> str:
        """Start the children; a one-line message saying what happened (never raises for a refusal)."""
        if not hasattr(os, "posix_spawn") or not hasattr(os, "SCHED_IDLE"):
            return "keep-awake unavailable on this platform (no SCHED_IDLE)"
        argv = [sys.executable, "-S", "-c", _SPIN, str(os.getpid())]
        try:  # spawned under normal scheduling (never a SCHED_FIFO parent's), then SCHED_IDLE by itself
            for _ in range(self.cores):
                self._pids.append(os.posix_spawn(sys.executable, argv, os.environ,
                                                 scheduler=(os.SCHED_OTHER, os.sched_param(0))))
        except OSError as exc:
            self.close()
            return f"keep-awake refused ({exc}): idle cores may halt"
        return f"keep-awake: {self.cores} SCHED_IDLE spinner(s) keep idle cores from halting"

    def close(self) -> None:
        """Stop and reap every child (idempotent)."""
        pids, self._pids = self._pids, []
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for pid in pids:
            try:
                os.waitpid(pid, 0)
            except ChildProcessError:
                pass

    def __enter__(self) -> "KeepAwake":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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
