"""A faulted run observed: the moment it is mid-episode, when the fault showed and when the run
went on, what its store and the agent said at the end."""
from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from ..waiting import wait_until
from .history import History, history
from .rig import TASK, Rig

__all__ = ["POLL_S", "PROGRESS", "RUN_S", "Outcome", "finish", "mid_episode", "recovered"]

RUN_S = 300.0
"""How long a run of a few episodes may take at most (bounds a hang; no statement of speed)."""
PROGRESS = r"episode +\d+/\d+ |update |run \S+ finished"
"""The daemon's lines of a run going as it should; any other line after a fault is its detection."""
POLL_S = 0.05
"""How often a harness reads the store it waits on."""


@dataclass(frozen=True)
class Outcome:
    """One faulted run: ``history``, its store at the end; ``during``, the store while the
    fault lasted (read once it took effect; ``None`` where the run went on meanwhile); the
    daemon's exit statuses (one per start, in order); ``detected_s``, seconds from the fault to
    its first sign (a daemon line other than progress, or the daemon's exit; ``None``: nothing
    showed); ``recovered_s``, seconds from the end of the fault (restart, link up) until the
    next ok episode was stored; ``output``, everything the daemon printed; ``answered``, the
    agent's own account of the episodes it ran to their end, (episode id, status) in order
    (whether or not its answer reached the daemon); ``hits``, what ``rogue.rogue_can`` hit."""

    fault: str
    history: History
    during: History | None
    exits: tuple[int, ...]
    detected_s: float | None
    recovered_s: float | None
    output: str
    answered: tuple[tuple[str, str], ...] = ()
    hits: tuple[tuple[str, int, int], ...] = ()


def mid_episode(rig: Rig, after: int) -> History:
    """Wait until ``after`` episodes are stored ok and the next one runs (its attempt pending);
    the store as it was then."""
    seen: list[History] = []

    def running() -> bool:
        h = history(rig.db)
        seen[:] = [h] if h else []
        return bool(h and len(h.episodes) >= after and any(status == "pending" for *_, status in h.attempts))
    wait_until(running, RUN_S, f"{after} ok episodes and one running", poll_s=POLL_S)
    return seen[0]


def recovered(rig: Rig, since_wall: float) -> float:
    """Seconds from ``since_wall`` (``time.time()``) to the first ok episode stored after it."""
    h = history(rig.db)
    later = [t for t in (h.finished if h else ()) if t is not None and t > since_wall]
    return min(later) - since_wall if later else float("nan")


def finish(rig: Rig, fault: str, during: History | None, exits: Sequence[int], t_fault: float,
           t_end_wall: float, detected: float | None = None) -> Outcome:
    """Let the daemon run to its end; the outcome."""
    code = rig.daemon_exit(RUN_S)
    if detected is None:
        seen = rig.first_line("daemon", t_fault, rf"^(?!{PROGRESS}).")
        detected = None if seen is None else seen - t_fault
    h = history(rig.db)
    assert h is not None
    answered = tuple(m.groups() for m in re.finditer(rf"episode (\S+) {TASK}: (\w+) cost", rig.output("agent")))
    return Outcome(fault, h, during, (*exits, code), detected, recovered(rig, t_end_wall), rig.output(), answered)
