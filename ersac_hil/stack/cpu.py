"""The CPU policy of a stack: how long the CAN-over-Zenoh buses busy-poll, from the processors
this process may run on."""
from __future__ import annotations

import os

__all__ = ["BUSY_POLL_S", "busy_poll_for"]

BUSY_POLL_S = 0.002
"""How long the simulators' and agents' CAN-over-Zenoh buses keep polling after each sample
(``--busy-poll``; ``ZenohBus(busy_poll=...)``): longer than a lock-step cycle's answer takes,
so a polling thread is never woken during an episode (docs/performance.md)."""


def busy_poll_for(pairs: int, cores: int | None = None) -> float:
    """The polling window of ``pairs`` simulator/agent pairs by default: ``BUSY_POLL_S`` while
    the machine has a core for each polling bus (two a pair), else 0. Measured on 2 cores: one
    polling pair ran 1.4x the episodes of one sleeping pair, two polling pairs 0.85x of two
    sleeping ones (docs/performance.md)."""
    if cores is None:  # the processors this process may run on (a container's affinity), else all
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return BUSY_POLL_S if 2 * pairs <= cores else 0.0
