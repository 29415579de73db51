"""End to end through every real process: Zenoh router, firmware simulator (MuJoCo, its CAN
bus listening for the agent's), agent (CANopen master) and learner daemon, started by
``ersac-hil demo``.

Checks the learning run in the store, the report files, and that no child outlives the demo,
also when the demo is interrupted with Ctrl-C (SIGINT).
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.daemon.store import Store
from helpers.processes import children, gone, group_killed_on_exit, lines_until
from protocol.zenoh import get_task

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl",
       "PYTHONUNBUFFERED": "1"}

pytestmark = pytest.mark.slow


def _demo(out: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "ersac_hil.cli", "demo", "--out", str(out), *args],
        cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)


def _demo_output(out: Path, *args: str, timeout_s: float) -> str:
    """Run a demo to its end (killed if it outlives ``timeout_s``); it must succeed."""
    with group_killed_on_exit(_demo(out, *args)) as proc:
        output, _ = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, output
    return output


def test_demo_learns_a_few_episodes_and_reports(tmp_path):
    out = tmp_path / "report"
    output = _demo_output(out, "--episodes", "3", "--seed", "4", "--kappa", "2", timeout_s=240)
    started = children(output)
    assert set(started) == {"router", "sim", "agent", "daemon"}  # CAN over Zenoh: no hub
    assert all(gone(pid) for pid in started.values()), output
    assert "episode    3/3" in output and f"report in {out}" in output
    assert re.search(r"3 episodes in \d+ s \(learning [\d.]+ s", output)

    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 3 and summary["status"] == "finished" and summary["kappa"] == 2.0
    for name in summary["files"]:
        assert (out / name).stat().st_size > 0
    assert {"learning_curve.png", "critic.png", "episode.png"} <= set(summary["files"])

    spec = get_task("bracing")
    with Store(out / "demo.db", readonly=True) as store:
        (run,) = store.runs()
        episodes = store.ok_episodes(run.run_id)
        updates = store.updates(run.run_id)
    assert [e.idx for e in episodes] == [0, 1, 2] and len(updates) == 3
    # the agent recorded every episode's time series (agent --record-series), the report drew them
    assert {e.episode_id for e in episodes} <= {p.stem for p in (out / "series").glob("*.npz")}
    for e in episodes:
        assert set(e.cost_terms) == set(spec.term_names)  # measured by the agent over CAN
        assert e.cost == pytest.approx(spec.total_cost(e.cost_terms))
        assert e.duration_s == pytest.approx(spec.horizon_s, abs=0.05) and e.wall_s > 0
        assert e.telemetry.get("n_cycles", 0) > 0
    for log in ("router", "sim", "agent", "daemon"):
        assert (out / "logs" / f"{log}.log").exists()


def test_ctrl_c_stops_every_child(tmp_path):
    with group_killed_on_exit(_demo(tmp_path / "report", "--episodes", "40", "--seed", "5")) as proc:
        lines = lines_until(proc, r"episode    1/40", 180)
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)  # a hang fails here
    output = "".join(lines) + rest
    assert proc.returncode == 130, output
    assert "interrupted" in output
    assert all(gone(pid) for pid in children(output).values()), output


def _stored(db: Path):
    with Store(db, readonly=True) as store:
        (run,) = store.runs()
        ok = store.ok_episodes(run.run_id)
        idx_of = {e.episode_id: e.idx for e in ok}
        return ([(e.idx, e.theta, e.seed, dict(e.cost_terms), e.update_idx) for e in ok],
                [(u.idx, u.theta_before, u.theta_after, u.J, u.r, dict(u.state), [idx_of[i] for i in u.episodes])
                 for u in store.updates(run.run_id)])


def test_a_fleet_of_two_pairs_learns_exactly_what_one_pair_learns(tmp_path):
    """``demo --fleet 2`` (two simulator/agent pairs, batch 2) against one pair with batch 2:
    the same episodes and updates, bit for bit, whichever simulator ran which episode."""
    runs = {}
    for name, args in (("fleet", ("--fleet", "2")), ("single", ("--batch", "2"))):
        out = tmp_path / name
        output = _demo_output(out, "--episodes", "4", "--seed", "6", *args, timeout_s=300)
        started = children(output)
        assert all(gone(pid) for pid in started.values()), output
        runs[name] = (output, started, _stored(out / "demo.db"))
    output, started, (episodes, updates) = runs["fleet"]
    assert {"sim1", "sim2", "agent1", "agent2", "daemon"} <= set(started)
    assert re.search(r"on ubot1\b(?!-)", output) and "on ubot1-2" in output  # both pairs served
    assert len(episodes) == 4 and [u[0] for u in updates] == [0, 1] and [u[-1] for u in updates] == [[0, 1], [2, 3]]
    assert runs["single"][2] == (episodes, updates)


@pytest.mark.parametrize("busy_poll", [0.0, 0.002])
def test_each_can_bus_gets_one_bus_kwargs_flag_with_its_identity_and_polling(tmp_path, busy_poll):
    """The children's CAN flags: the role's identity and the busy polling in one
    ``--bus-kwargs`` (a second flag would replace the first), parsed as keyword arguments."""
    import threading

    from ersac_hil.stack import Stack
    from protocol.can.busconfig import parse_bus_kwargs
    stack = Stack(tmp_path / "logs", threading.Event(), busy_poll=busy_poll)  # explicit: any core count
    stack.roles = {"agent": "agent.json5", "simulator": "simulator.json5"}
    sim, channel = stack._direct_listener("ersac-ubot1")
    for argv, role, first in ((sim, "simulator", (("listen", channel.split("@")[1]),)),
                              (stack.can_args("agent", channel), "agent", ())):
        assert argv.count("--bus-kwargs") == 1
        expected = (*first, ("zenoh_config", f"{role}.json5"),
                    *((("busy_poll", str(busy_poll)),) if busy_poll else ()))
        assert parse_bus_kwargs(argv[argv.index("--bus-kwargs") + 1:]) == expected
    stack.roles = {}
    assert ("--bus-kwargs" in stack.can_args("agent", channel)) == bool(busy_poll)


@pytest.mark.parametrize("pairs, cores, expected", [(1, 2, 0.002), (2, 2, 0.0), (2, 4, 0.002), (3, 4, 0.0),
                                                    (1, 1, 0.0)])
def test_pairs_poll_by_default_only_with_a_core_for_each_polling_bus(pairs, cores, expected):
    from ersac_hil.stack import BUSY_POLL_S, busy_poll_for
    assert busy_poll_for(pairs, cores) == (BUSY_POLL_S if expected else 0.0)
