"""The CPU policy of a stack, from the processors this process may run on (``usable_cores``: a
container's or taskset's affinity, not the machine's): how many simulator/agent pairs may start
(``check_pairs``) and how long the CAN-over-Zenoh buses busy-poll (``busy_poll_for``)."""
from __future__ import annotations

import os

__all__ = ["BUSY_POLL_S", "PAIRS_PER_CORE", "TooManyPairs", "busy_poll_for", "check_pairs", "max_pairs",
           "usable_cores"]

BUSY_POLL_S = 0.002
"""How long the simulators' and agents' CAN-over-Zenoh buses keep polling after each sample
(``--busy-poll``; ``ZenohBus(busy_poll=...)``): longer than a lock-step cycle's answer takes,
so a polling thread is never woken during an episode (docs/performance.md)."""


def busy_poll_for(pairs: int, cores: int | None = None) -> float:
    """The polling window of ``pairs`` simulator/agent pairs by default: ``BUSY_POLL_S`` while
    the machine has a core for each polling bus (two a pair), else 0. Measured on 2 cores: one
    polling pair ran 1.4x the episodes of one sleeping pair, two polling pairs 0.85x of two
    sleeping ones (docs/performance.md)."""
    cores = usable_cores() if cores is None else cores
    return BUSY_POLL_S if 2 * pairs <= cores else 0.0


PAIRS_PER_CORE = 2
"""Simulator/agent pairs allowed per usable core. In lock-step a pair's simulator and agent
hand every SYNC cycle to each other, so a pair keeps at most one core busy: two pairs on two
cores ran 2.05x the episodes of one (``bench/fleet.py``, docs/performance.md), and a pair more
than cores adds load, not episodes. Two a core leave room for pairs that wait (for their
daemon's updates, for a learner's fits, sleeping between real-time SYNCs); far beyond it the
machine only starts simulators (217 of them on 2 cores: load above 500, no episode in 9 min)."""


class TooManyPairs(ValueError):
    """More simulator/agent pairs than the cores this process may use can run."""


def usable_cores() -> int:
    """The processors this process may run on (its affinity: a container's or taskset's), else
    the machine's."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def max_pairs(cores: int | None = None) -> int:
    """The most simulator/agent pairs ``cores`` (default :func:`usable_cores`) run."""
    return PAIRS_PER_CORE * (usable_cores() if cores is None else cores)


def check_pairs(pairs: int, flag: str, override: str, cores: int | None = None) -> None:
    """Refuse ``pairs`` above :func:`max_pairs`, in one line naming ``flag`` and the ``override``
    flag that starts them anyway.

    Raises:
        TooManyPairs.
    """
    cores = usable_cores() if cores is None else cores
    if pairs > max_pairs(cores):
        raise TooManyPairs(
            f"{flag} {pairs}: this process may use {cores} core(s), which run at most {max_pairs(cores)} "
            f"simulator/agent pairs ({PAIRS_PER_CORE} a core); {override} starts them anyway")
