"""A fleet behind one learner, with real processes: daemons and synthetic agents as separate
processes on a real router. The same run (seed, batch) gives bit-identical episodes and
updates with one or two agents; an agent SIGKILLed mid-episode loses nothing; a daemon
SIGKILLed mid-batch resumes without running a stored episode again; batch 1 is the paper's
ask/tell bit for bit."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.daemon.config import ConfigError, DaemonConfig, merge
from ersac_hil.daemon.engine import Engine
from ersac_hil.daemon.report import write_report
from ersac_hil.daemon.store import Store
from helpers import synthetic_agent
from helpers.waiting import wait_for_store

ROOT = Path(__file__).resolve().parents[3]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
EPISODES = 16


class Agents:
    """Synthetic agent processes (``--delay``: each episode takes that long); killed at exit."""

    def __init__(self, router) -> None:  # noqa: ANN001
        self.router, self.procs = router, {}

    def start(self, robot: str, delay: float = 0.05) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, synthetic_agent.__file__, "--robot", robot, "--zenoh",
                                 self.router.endpoint, "--delay", repr(delay), "--fault-every", "5",
                                 "--refuse-above", "0.75"], env=ENV, stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "synthetic agent ready"
        self.procs[robot] = proc
        return proc

    def close(self) -> None:
        for proc in self.procs.values():
            proc.kill()
            proc.wait(10)


@pytest.fixture
def agents(router):
    made = Agents(router)
    yield made
    made.close()


def _daemon_cmd(router, db: Path, robots: list[str], batch: int) -> list[str]:  # noqa: ANN001
    flags = [a for r in robots for a in ("--robot", r)]
    return [sys.executable, "-m", "ersac_hil.cli", "daemon", *flags, "--batch", str(batch),
            "--zenoh", router.endpoint, "--db", str(db), "--episodes", str(EPISODES), "--seed", "5",
            "--kappa", "1.0", "--theta0", "0.6", "--sigma", "0.1", "--backoff", "0.05,0.2", "--max-attempts", "10"]


def _run(router, db: Path, robots: list[str], batch: int) -> str:  # noqa: ANN001
    done = subprocess.run(_daemon_cmd(router, db, robots, batch), env=ENV, cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def _history(db: Path):
    """What must not depend on which agent ran what: every ok episode (idx, theta, seed, cost
    terms, cost, update) and every update (numbers, state, which episodes fed it)."""
    with Store(db, readonly=True) as store:
        (run,) = store.runs()
        ok = store.ok_episodes(run.run_id)
        idx_of = {e.episode_id: e.idx for e in ok}
        episodes = [(e.idx, e.base_theta, e.theta, e.seed, dict(e.cost_terms), e.cost, e.update_idx) for e in ok]
        updates = [(u.idx, u.theta_before, u.theta_after, u.cost, u.J, u.r, u.r_z, u.td_error, u.kappa, u.lr,
                    dict(u.state), [idx_of[e] for e in u.episodes]) for u in store.updates(run.run_id)]
        return run, episodes, updates, store.attempts(run.run_id)


def test_one_or_two_agents_give_bit_identical_runs_and_a_killed_agent_loses_nothing(router, agents, tmp_path):
    agents.start("fa")
    one = tmp_path / "one.db"
    _run(router, one, ["fa"], batch=2)
    ref_run, ref_eps, ref_updates, ref_attempts = _history(one)
    assert ref_run.status == "finished" and len(ref_eps) == EPISODES and len(ref_updates) == EPISODES // 2
    assert any(a.status == "refused" for a in ref_attempts)  # redraws inside batches
    assert any(a.status == "fault_pdo_timeout" for a in ref_attempts)  # retries inside batches
    assert any(u[4] is not None for u in ref_updates)  # past the critic's warm-up

    # two agents: one named, one found through a key expression
    agents.start("fb")
    two = tmp_path / "two.db"
    out = _run(router, two, ["fa", "f$*"], batch=2)
    run, eps, updates, _ = _history(two)
    assert "on fa" in out and "on fb" in out  # both agents served the run
    assert eps == ref_eps and updates == ref_updates  # bit for bit
    summary = write_report(two, run.run_id, tmp_path / "report")  # plots one update per batch
    assert (summary["episodes"], summary["learner_updates"]) == (EPISODES, EPISODES // 2)

    # an agent SIGKILLed mid-episode: its request goes to the other one; nothing lost
    slow = agents.start("fc", delay=60.0)  # the first episode it takes is running when it is killed
    killed = tmp_path / "killed.db"
    proc = subprocess.Popen(_daemon_cmd(router, killed, ["fa", "fc"], 2), env=ENV, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        running = slow.stdout.readline().split()[-1]  # "running <episode id>"
        slow.send_signal(signal.SIGKILL)
        out, _ = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    run, eps, updates, attempts = _history(killed)
    (lost,) = [a for a in attempts if a.status == "lost"]
    assert lost.episode_id == running, out
    again = next(e for e in attempts if e.idx == lost.idx and e.ok)  # the same request, re-sent
    assert (again.theta, again.seed) == (lost.theta, lost.seed) and again.attempt > lost.attempt
    assert eps == ref_eps and updates == ref_updates


def test_a_daemon_killed_mid_batch_resumes_without_repeating_an_episode(router, agents, tmp_path):
    agents.start("ra", delay=0.05)
    agents.start("rb", delay=1.0)  # a batch's episodes on ra end while rb's still runs
    reference = tmp_path / "ref.db"
    _run(router, reference, ["ra"], batch=3)
    ref = _history(reference)
    killed = tmp_path / "killed.db"
    proc = subprocess.Popen(_daemon_cmd(router, killed, ["ra", "rb"], 3), env=ENV, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def mid_batch(store: Store, run_id: str) -> bool:  # an ok episode waits for its batch
        return any(e.update_idx is None for e in store.ok_episodes(run_id)) and store.update_count(run_id) >= 1
    try:
        wait_for_store(killed, mid_batch)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        proc.kill()
    with Store(killed, readonly=True) as store:
        waiting = [e.episode_id for e in store.ok_episodes(store.runs()[0].run_id) if e.update_idx is None]
    out = _run(router, killed, ["ra", "rb"], batch=3)
    assert "resumed at episode" in out
    run, eps, updates, attempts = _history(killed)
    assert eps == ref[1] and updates == ref[2]
    ok_ids = [a.episode_id for a in attempts if a.ok]
    assert set(waiting) <= set(ok_ids) and len(ok_ids) == EPISODES  # stored ones were not run again


def test_batch_1_is_the_papers_ask_tell(router, agent_factory, daemon_factory):
    """A daemon run with the default batch equals ERSAC's ask()/tell() fed the same costs."""
    agent_factory("plain")
    daemon = daemon_factory("plain", episodes=14, kappa=2.0)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with Store(daemon.config.db, readonly=True) as store:
        run = store.run(daemon.learning.run_id)
        eps, updates = store.ok_episodes(run.run_id), store.updates(run.run_id)
    learner = Engine.create(run.task, run.settings)._learner  # the same ERSAC the daemon built
    for e, u in zip(eps, updates, strict=True):
        x = learner.ask()
        assert tuple(x) == e.theta and u.episodes == (e.episode_id,)
        step = learner.tell(x, dict(e.cost_terms))
        assert (tuple(step.theta_after), step.J_tilde, step.r_tilde) == (u.theta_after, u.J, u.r)
    assert learner.get_state() == updates[-1].state


def test_fleet_and_batch_configuration():
    config = merge({"robot": "ubot1", "fleet": ["ubot2", "lab$*"], "batch": 3}, {"kappa": 1.0})
    assert config.sources == ("ubot1", "ubot2", "lab$*") and config.batch == 3
    assert config.learner_settings()["batch"] == 3
    assert DaemonConfig(robot="a", fleet=("a", "b")).sources == ("a", "b")
    for bad in ({"fleet": ("ubot*",)}, {"fleet": ("a/b",)}, {"fleet": ("**",)}, {"batch": 0}):
        with pytest.raises(ConfigError):
            DaemonConfig(robot="a", **bad)
    with pytest.raises(ConfigError, match="plain name"):
        DaemonConfig(robot="ubot$*")


def test_bad_fleet_flags_are_refused_before_anything_starts(tmp_path):
    for flags in (["--robot", "u$*"], ["--robot", "u1", "--robot", "u*"], ["--robot", "u1", "--batch", "0"]):
        done = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "daemon", *flags, "--db",
                               str(tmp_path / "x.db")], env=ENV, cwd=ROOT, capture_output=True, text=True,
                              timeout=60)
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert not (tmp_path / "x.db").exists()


def test_batch_is_a_learner_setting_of_the_run(tmp_path):
    """A resumed run keeps its batch; a different explicit one is refused."""
    from ersac_hil.daemon.runs import open_run
    with Store(tmp_path / "b.db") as store:
        run, config, resumed = open_run(store, DaemonConfig(robot="r", batch=2, seed=1, resume="new"))
        assert run.settings["batch"] == 2 and not resumed
        again, config, resumed = open_run(store, DaemonConfig(robot="r"))
        assert resumed and config.batch == 2
        with pytest.raises(ConfigError, match="batch"):
            open_run(store, merge({}, {"robot": "r", "batch": 3}))
