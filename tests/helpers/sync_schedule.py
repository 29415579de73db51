"""Whether SYNCs heard on a bus went out ahead of a real-time pacer's schedule.

The agent's pacer (``AgentBus._pace``) sends the k-th SYNC at or after its slot; slots are
``period_s`` apart and re-phased only later, never earlier (a cycle more than a slot behind
starts a new schedule at the present). So the slot's phase ``slot_k - k * period_s`` never
decreases, and a SYNC whose phase ``t_k - k * period_s`` falls below an earlier slot's phase
went out ahead of its own.

The slots are not on the bus, only the sends: each send is its slot plus a lateness, small but
now and then large on a loaded machine (the agent preempted between its slot and its send). The
floor a SYNC is held to is therefore a low quantile of the phases of the SYNCs before it, which
a few late ones do not lift and a re-phase (later phases after earlier ones) never does. A
false alarm would take most of the SYNCs before one being late by more than the tolerance.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

WINDOW = 20
"""How many SYNCs before one give its floor."""
SETTLE = 5
"""The first SYNCs have too few before them for a floor (the first may itself be late)."""
QUANTILE = 0.2
"""The floor: this quantile of the ``WINDOW`` phases before (the 4th lowest of 20)."""


def ahead_of_schedule(stamps: ArrayLike, period_s: float, tolerance_s: float = 1e-3) -> list[int]:
    """The indices of the SYNCs sent more than ``tolerance_s`` ahead of the schedule.

    Args:
        stamps: shape ``(n,)``, each SYNC's send time in seconds (any one clock), in order.
        period_s: the schedule's period.

    Lock-step (SYNCs as fast as the answers come) and any period 10 % or more too short
    (phases falling ``0.1 * period_s`` a cycle: the floor 4 cycles back, 2 ms above at 5 ms)
    are flagged from the ``SETTLE``-th SYNC on.
    """
    stamps = np.asarray(stamps, dtype=float)
    phase = stamps - np.arange(len(stamps)) * period_s
    early = []
    for k in range(SETTLE, len(phase)):
        floor = np.quantile(phase[max(0, k - WINDOW):k], QUANTILE, method="lower")
        if phase[k] < floor - tolerance_s:
            early.append(k)
    return early
