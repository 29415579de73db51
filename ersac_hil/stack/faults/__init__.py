"""Faults of a real deployment, injected into a real stack: the Zenoh router, the firmware
simulator, the agent and the learner daemon as separate processes (``ersac-hil router/sim/
agent/daemon``), each of which can be killed, restarted, cut off or starved of disk, and what a
run's store holds afterwards compared with an uninterrupted run of the same seed.

Used by ``tests/e2e/test_faults.py`` (asserts) and ``bench/chaos.py`` (measures and prints),
on the stack's own process supervision (``Child``: a process group each, a log file, gone with
this process). No pytest in here: the bench runs without it. Network namespaces need root.

The harness by job: ``rig`` (the processes, started and stopped one by one), ``netns`` (the
namespace pair of the network faults), ``processes`` and ``rogue`` (each fault's injection),
``outcome`` and ``history`` (what a faulted run did and its store holds, against the run
without the fault); here the faults by name.
"""
from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .history import History, Tally, history, n_ok, tally
from .netns import Netns, netns_unavailable
from .outcome import RUN_S, Outcome
from .processes import disk_full, kill_all, partition, router_restart
from .rig import ROBOT, START_S, Rig, reference_run
from .rogue import ROGUE_NODES, robot_cob_ids, rogue_can, rogue_frames

__all__ = ["FAULTS", "NETNS_FAULTS", "ROBOT", "ROGUE_NODES", "RUN_S", "START_S", "History", "Netns", "Outcome",
           "Rig", "Tally", "disk_full", "faulted_rig", "history", "kill_all", "n_ok", "netns_unavailable",
           "partition", "reference_run", "robot_cob_ids", "rogue_can", "rogue_frames", "router_restart", "tally"]

FAULTS: dict[str, Callable[[Rig], Outcome]] = {
    "kill-all": kill_all, "router-restart": router_restart, "disk-full": disk_full, "partition": partition,
    "partition-agent": partition, **{f"rogue-{kind}": functools.partial(rogue_can, kind=kind) for kind in ROGUE_NODES}}
NETNS_FAULTS = {"partition": "robot", "partition-agent": "daemon"}
"""The faults run across two network namespaces -> the namespace of the router (``Rig.router_beside``;
the other side is the one cut off)."""


@contextmanager
def faulted_rig(fault: str, work: Path, seed: int, episodes: int) -> Iterator[Rig]:
    """The rig ``fault`` runs on (across a namespace pair made here and deleted after, for the
    faults of :data:`NETNS_FAULTS`); every child stopped at the end."""
    beside = NETNS_FAULTS.get(fault)
    netns = Netns() if beside else None
    try:
        with Rig(work, seed, episodes, netns, router_beside=beside or "robot") as rig:
            yield rig
    finally:
        if netns is not None:
            netns.close()
