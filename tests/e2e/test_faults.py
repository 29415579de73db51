"""The faults of a real deployment, each against the run without it: router, simulator, agent
and daemon as separate processes (``ersac_hil.stack.faults.Rig``), a real SQLite store, Zenoh on
loopback (the partition: across two network namespaces the test makes). After each fault the
run must end by itself with exactly the ok episodes and updates of the uninterrupted run, bit
for bit: none lost, none recorded twice, the interrupted episode run again.

A few lock-step bracing episodes each; every test takes 20-60 s on an idle two-core machine,
hence ``slow`` like the rest of tests/e2e.
"""
from __future__ import annotations

import re
import signal
import subprocess

import pytest

from ersac_hil.daemon.service import EXIT_STORE
from ersac_hil.stack.faults import (ROGUE_NODES, RUN_S, History, Netns, Outcome, Rig, disk_full, kill_all,
                            netns_unavailable, partition, reference_run, rogue_can, router_restart, tally)
from helpers.processes import gone

pytestmark = pytest.mark.slow

SEED, EPISODES = 3, 6


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> History:
    return reference_run(tmp_path_factory.mktemp("reference"), SEED, EPISODES, RUN_S)


@pytest.fixture
def rig(tmp_path):
    rig = Rig(tmp_path, SEED, EPISODES)
    yield rig
    rig.close()
    assert all(gone(pid) for pid in rig.pids)


def _exact(reference: History, outcome: Outcome) -> None:
    """The faulted run finished with the reference's episodes and updates, bit for bit; every
    attempt the fault cut short was run again."""
    h = outcome.history
    assert h.status == "finished", outcome.output
    assert tally(reference, h).exact, outcome.output
    assert h.episodes == reference.episodes and h.updates == reference.updates
    ok = {idx for idx, _, status in h.attempts if status == "ok"}
    cut = [(idx, attempt) for idx, attempt, status in h.attempts if status not in ("ok", "pending")]
    assert all(idx in ok for idx, _ in cut) and not any(s == "pending" for *_, s in h.attempts)


def test_every_process_killed_at_once_mid_episode_resumes_exactly(reference, rig):
    outcome = kill_all(rig)
    during = outcome.during
    assert during is not None and during.status == "running"  # the store opens, the run resumable
    assert [s for *_, s in during.attempts].count("pending") == 1  # killed mid-episode
    assert outcome.exits == (-signal.SIGKILL, 0), outcome.output
    assert "(resumed at episode 3, 1 interrupted attempt(s))" in outcome.output
    _exact(reference, outcome)
    (interrupted,) = [(idx, a) for idx, a, s in outcome.history.attempts if s == "interrupted"]
    assert (interrupted[0], interrupted[1] + 1, "ok") in outcome.history.attempts  # re-run, counted once


def test_a_restarted_router_loses_nothing(reference, rig):
    outcome = router_restart(rig)
    assert outcome.exits == (0,), outcome.output  # one daemon start: the sessions reconnected
    _exact(reference, outcome)


def test_a_full_disk_stops_the_run_with_exit_5_and_a_restart_resumes(reference, rig):
    outcome = disk_full(rig)
    assert outcome.exits == (EXIT_STORE, 0), outcome.output
    reason = [line for line in outcome.output.splitlines() if "cannot be written" in line]
    assert len(reason) == 1 and "Traceback" not in outcome.output, outcome.output
    assert str(rig.db) in reason[0] and "the run stays resumable" in reason[0]
    during = outcome.during
    assert during is not None and during.status == "running"  # it opens, nothing half-written
    assert during.episodes == reference.episodes[:len(during.episodes)]
    assert during.updates == reference.updates[:len(during.updates)] and len(during.episodes) >= 2
    _exact(reference, outcome)


@pytest.fixture
def netns():
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"no network namespaces here: {reason}")
    made = Netns()
    yield made
    made.close()
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert made.daemon not in listed and made.robot not in listed


def test_a_partition_between_daemon_and_robot_heals_and_loses_nothing(reference, tmp_path, netns):
    with Rig(tmp_path, SEED, EPISODES, netns) as rig:
        outcome = partition(rig)
    assert all(gone(pid) for pid in rig.pids)
    assert outcome.exits == (0,), outcome.output
    assert outcome.detected_s is not None, outcome.output  # the daemon saw the agent go
    _exact(reference, outcome)


def test_a_partition_of_the_agent_retries_the_episode_and_takes_no_late_answer(reference, tmp_path, netns):
    """The agent and its simulator cut off from the router (beside the daemon) for 12 s
    mid-episode: the agent runs the episode to its end and answers into the cut; the daemon sees
    the agent vanish (``lost``) and, once the agent's session is back (the same Zenoh session,
    its tokens and queryable declared again), asks the episode again under a new request id
    (``<run>.<idx>.<attempt>``). The agent's answer to the cut attempt is never taken for the
    retry's (the daemon takes a reply only to its own query, from a session holding the
    agent's session token, for the id it asked: test_daemon.py tests the last with such a late
    answer in the retry's query), and the run ends exactly as without the cut."""
    with Rig(tmp_path, SEED, EPISODES, netns, router_beside="daemon") as rig:
        outcome = partition(rig)
    assert all(gone(pid) for pid in rig.pids)
    assert outcome.exits == (0,), outcome.output
    assert outcome.detected_s is not None, outcome.output  # the daemon saw the agent go
    assert outcome.during is not None
    (hit,) = [(idx, attempt) for idx, attempt, status in outcome.during.attempts if status == "pending"]
    attempts = outcome.history.attempts
    assert (*hit, "lost") in attempts, (hit, attempts, outcome.output)
    answered = [status for eid, status in outcome.answered if eid.endswith(f".{hit[0]:05d}.{hit[1]}")]
    assert answered == ["ok"], (hit, outcome.answered)  # run to its end behind the cut; not taken
    (ok,) = [attempt for idx, attempt, status in attempts if idx == hit[0] and status == "ok"]
    assert ok > hit[1]  # the retry, under its own id
    _exact(reference, outcome)


REASON = {"sync": "a frame of 0x080, which no node of the robot sends", "tpdo-twice": "twice in one cycle",
          "wrong-length": "bytes, its map has", "sdo-answer": "an SDO answer from imu to no request",
          "babbler": "a frame of 0x001, which no node of the robot sends", "error-frame": "error frame 0x000"}
"""What the agent names as the fault of each faulty node (``ROGUE_NODES``)."""


def test_faulty_can_nodes_fault_the_episodes_they_hit_and_nothing_of_them_is_learned(reference, rig):
    """Faulty nodes on the robot's bus, one kind an episode (``ROGUE_NODES``: a second SYNC
    producer, a forged TPDO of the right length, PDOs of the wrong length, unsolicited SDO
    answers, a babbler on a high-priority id, error frames; each while the episode it hit runs,
    the next once the episode before is ok): the agent lives on, every attempt a node hit ends
    as a bus fault naming what the node sent (measured before for SYNC and forged TPDOs: ok with
    other costs), is run again once the node is gone, and the run learns exactly what it learns
    without them. One run for all kinds (a stack start each would cost more than the faults)."""
    outcome = rogue_can(rig, *ROGUE_NODES, after=0)
    assert outcome.exits == (0,), outcome.output
    assert [kind for kind, *_ in outcome.hits] == list(ROGUE_NODES)
    for kind, *hit in outcome.hits:
        (status,) = [s for idx, attempt, s in outcome.history.attempts if [idx, attempt] == hit]
        assert status.startswith("fault_"), (kind, status, outcome.output)
        said = rf"^episode +{hit[0] + 1} attempt {hit[1] + 1}: {status} \(SYNC cycle \d+: .*{re.escape(REASON[kind])}"
        assert re.search(said, outcome.output, re.M), (kind, outcome.output)  # as what it is (printed 1-based)
    assert rig.children["agent"].alive(), "the agent crashed"
    _exact(reference, outcome)
