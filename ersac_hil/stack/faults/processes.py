"""The faults of the processes and the network between them: every process killed at once, the
router restarted, the daemon's disk full, a partition between the two namespaces."""
from __future__ import annotations

import re
import signal
import time

from ..waiting import wait_until
from .history import History, history, n_ok
from .outcome import POLL_S, RUN_S, Outcome, finish, mid_episode
from .rig import TASK, Rig

__all__ = ["PARTITION_S", "disk_full", "kill_all", "partition", "router_restart"]

PARTITION_S = 12.0
"""How long the partition lasts: longer than Zenoh's lease (10 s, the default
``transport/link/tx/lease``), so the cut-off session surely expires. A cut of about the lease
races its expiry (measured: detected after 9.9-10.0 s of a 10 s cut), and a shorter one TCP
bridges: the session lives on and nothing is to recover."""


def kill_all(rig: Rig) -> Outcome:
    """Every process SIGKILLed at once mid-episode, then the whole stack started again."""
    rig.start()
    mid_episode(rig, 2)
    t_fault = time.monotonic()
    rig.kill()
    during = history(rig.db)
    t_end_wall = time.time()
    rig.start()
    seen = rig.first_line("daemon", t_fault, r"interrupted attempt")
    return finish(rig, "kill-all", during, (-signal.SIGKILL,), t_fault, t_end_wall,
                  None if seen is None else seen - t_fault)


def router_restart(rig: Rig) -> Outcome:
    """The router SIGKILLed mid-episode and started again on its endpoint; the others stay."""
    rig.start()
    mid_episode(rig, 2)
    t_fault = time.monotonic()
    rig.kill("router")
    rig.start_router()
    return finish(rig, "router-restart", None, (), t_fault, time.time())


def disk_full(rig: Rig) -> Outcome:
    """No file of the daemon may grow any more (``RLIMIT_FSIZE`` 0: every write fails) after
    two episodes: the daemon must stop the run by itself; then a daemon with space resumes it."""
    rig.start()
    wait_until(lambda: n_ok(rig.db) >= 2, RUN_S, "2 ok episodes", poll_s=POLL_S)
    t_fault = time.monotonic()
    rig.limit_file_size("daemon", 0)
    code = rig.daemon_exit(RUN_S)
    detected = time.monotonic() - t_fault
    during = history(rig.db)
    t_end_wall = time.time()
    rig.start_daemon()
    return finish(rig, "disk-full", during, (code,), t_fault, t_end_wall, detected)


def partition(rig: Rig) -> Outcome:
    """The link between the two namespaces down for ``PARTITION_S`` mid-episode, then up: the
    side without the router (``Rig.cut_off``: the daemon, or the agent with its simulator) cut
    off. ``during``: the store when the link went down (the attempt it cut pending)."""
    assert rig.netns is not None
    rig.start()
    during, t_fault = _cut_mid_episode(rig, 2)
    try:
        time.sleep(PARTITION_S)  # the fault's duration, not a synchronisation
    finally:
        rig.netns.link(True, rig.cut_off)
    return finish(rig, "partition" if rig.cut_off == "daemon" else "partition-agent", during, (), t_fault,
                  time.time())


def _cut_mid_episode(rig: Rig, after: int) -> tuple[History, float]:
    """Take the link down while an episode runs, once ``after`` episodes are ok: the store once
    the link is down, and when it went down (``time.monotonic()``).

    An episode takes a few tenths of a second, about what starting ``ip`` can take on a loaded
    machine: the attempt seen running may have ended before the link went down, or not have
    begun - the store marks it pending when the daemon sends the query, which on a loaded
    machine can still be on its way. The cut is kept only if the agent had started that attempt
    and it still runs once the link is down (its "started" line logged, no answer logged, not
    stored ok); else the link goes up at once (a cut of milliseconds the TCP links bridge) and
    the next episode is tried."""
    assert rig.netns is not None
    while True:
        running = [(idx, attempt) for idx, attempt, status in mid_episode(rig, after).attempts if status == "pending"]
        t_fault = time.monotonic()
        rig.netns.link(False, rig.cut_off)
        during = history(rig.db)
        assert during is not None
        answered = rig.output("agent")
        if all((idx, attempt, "pending") in during.attempts and f".{idx:05d}.{attempt} {TASK}: started" in answered
               and not re.search(rf"\.{idx:05d}\.{attempt} {TASK}: \w+ cost", answered)
               for idx, attempt in running):
            return during, t_fault
        rig.netns.link(True, rig.cut_off)
        after = len({e[0] for e in during.episodes} | {idx for idx, _ in running})  # the next one's turn
        if after >= rig.episodes:
            raise RuntimeError(f"no episode of the {rig.episodes} ran long enough to be cut")
