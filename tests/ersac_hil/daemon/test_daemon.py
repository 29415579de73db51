"""The daemon against the synthetic agent over a real Zenoh router: configuration, kappa
changes mid-run, an absent or vanishing agent, failed episodes, and resume after SIGKILL."""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from ersac_hil.daemon.clients import LearnerClient
from ersac_hil.daemon.config import ConfigError, DaemonConfig, load_toml, merge
from ersac_hil.daemon.runs import open_run, rebuild_engine, scenario_seed
from ersac_hil.daemon.service import EXIT_FAILED, EXIT_STORE, MAX_REDRAWS
from ersac_hil.daemon.store import Store
from helpers import synthetic_agent
from helpers.synthetic_agent import synthetic_terms
from helpers.waiting import wait_for_store, wait_until
from protocol.zenoh import KeySpace

ROOT = Path(__file__).resolve().parents[3]


# --------------------------------------------------------------------------- configuration
def test_config_defaults_file_and_flags(tmp_path):
    path = tmp_path / "d.toml"
    path.write_text('robot = "ubot9"\nkappa = 1.5\nepisodes = 30\nzenoh = "tcp/127.0.0.1:7999"\n'
                    'theta0 = [0.35]\n[weights]\ndamage = 20.0\n')
    config = merge(load_toml(path), {"kappa": 2.0, "weights": {"arm_power": 1.0}, "task": None})
    assert config.robot == "ubot9" and config.kappa == 2.0 and config.episodes == 30  # flags win
    assert config.zenoh == ("tcp/127.0.0.1:7999",) and config.theta0 == (0.35,)
    assert config.weights == {"damage": 20.0, "body_acc_sq": 0.1, "arm_power": 1.0}
    assert config.sigma == (0.05,) and config.task == "bracing"
    assert {"kappa", "weights", "robot", "theta0"} <= config.explicit and "sigma" not in config.explicit
    lifting = DaemonConfig(robot="r", task="lifting")
    assert len(lifting.theta0) == 7 and len(lifting.sigma) == 7


def test_the_papers_settings_are_the_defaults_per_task():
    bracing = DaemonConfig(robot="r")
    assert (bracing.sigma, bracing.eta, bracing.epsilon, bracing.lr_range) == ((0.05,), 0.7, 0.2, (0.01, 0.5))
    assert bracing.episodes_or_default == 45 and bracing.theta0[0] < 0.5  # from a low stiffness
    lifting = DaemonConfig(robot="r", task="lifting")
    assert lifting.sigma == (0.075,) * 7 and lifting.eta == 0.5 and lifting.lr_range == (0.01, 0.5)
    assert lifting.epsilon == pytest.approx(3.5 * 0.075) and lifting.episodes_or_default == 30
    given = DaemonConfig(robot="r", task="lifting", eta=0.2, epsilon=0.3, episodes=5)
    assert (given.eta, given.epsilon, given.episodes_or_default) == (0.2, 0.3, 5)


@pytest.mark.parametrize("text, match", [
    ('robot = "r"\ncolour = 3\n', "unknown keys"),
    ('robot = "r"\nkappa = 99\n', "kappa"),
    ('robot = "r"\ntheta0 = [1.5]\n', "theta0"),
    ('robot = "r"\ntheta0 = [0.1, 0.2]\n', "theta0"),
    ('robot = "r"\nzenoh = ["tcp/0.0.0.0:7447"]\n', "loopback"),
    ('robot = "a/b"\n', "robot"),
    ('robot = "r"\n[weights]\ngravity = 1.0\n', "gravity"),
    ('robot = "r"\nsigma = [0.0]\n', "sigma"),
    ('robot = "r"\nlr_range = [0.5, 0.1]\n', "lr_range"),
    ('kappa = 1.0\n', "robot"),
    ('robot = "r"\nkappa = \n', "TOML"),
])
def test_bad_configs_are_refused(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        merge(load_toml(path), {})


def test_resume_rules(tmp_path):
    with Store(tmp_path / "r.db") as store:
        base = dict(robot="r", db=tmp_path / "r.db", seed=3, kappa=2.0)
        run, config, resumed = open_run(store, DaemonConfig(**base))
        assert not resumed and run.seed == 3 and run.settings["episodes"] == 45
        again, _, resumed = open_run(store, merge({}, {**base, "episodes": 50}))
        assert resumed and again.run_id == run.run_id and again.settings["episodes"] == 50
        with pytest.raises(ConfigError, match="kappa=2.0"):
            open_run(store, merge({}, {**base, "kappa": 0.0}))
        other, _, resumed = open_run(store, merge({}, {**base, "kappa": 0.0, "resume": "new"}))
        assert not resumed and other.run_id != run.run_id
        with pytest.raises(ConfigError, match="no run"):
            open_run(store, DaemonConfig(robot="r", resume="nope"))
        with pytest.raises(ConfigError, match="lifting"):
            open_run(store, DaemonConfig(robot="r", task="lifting", resume=run.run_id))
    assert scenario_seed(3, 0) == scenario_seed(3, 0) != scenario_seed(3, 1) != scenario_seed(4, 1)


# --------------------------------------------------------------------------- learning
def test_kappa_change_mid_run_is_used_from_the_next_update(router, agent_factory, daemon_factory):
    agent_factory("kap", delay_s=0.05)
    daemon = daemon_factory("kap", episodes=16, kappa=0.0)
    with LearnerClient(KeySpace("kap"), [router.endpoint], timeout_s=20) as client:
        wait_until(lambda: client.state().episode_count >= 6)
        client.set_kappa(3.0)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with Store(daemon.config.db, readonly=True) as store:
        run = daemon.learning.run_id
        change = store.latest_change(run, "kappa")
        kappas = [u.kappa for u in store.updates(run)]
    k = change.n_updates
    assert change.value == 3.0 and 6 <= k < 16
    assert kappas == [0.0] * k + [3.0] * (16 - k)


def test_agent_absent_then_lost_mid_episode_then_back(router, daemon_factory, tmp_path):
    out = io.StringIO()
    daemon = daemon_factory("gone", episodes=6, out=out)
    wait_until(lambda: "waiting for the agent" in out.getvalue())
    assert daemon.handlers.state().status == "paused"
    cmd = [sys.executable, synthetic_agent.__file__, "--robot", "gone", "--zenoh", router.endpoint]
    slow = subprocess.Popen([*cmd, "--delay", "30"], stdout=subprocess.PIPE, text=True)
    try:
        with Store(daemon.config.db, readonly=True) as store:
            wait_until(lambda: store.attempts(daemon.learning.run_id, "pending"))
            slow.send_signal(signal.SIGKILL)  # the agent dies mid-episode
            wait_until(lambda: store.attempts(daemon.learning.run_id, "lost"), timeout_s=10)
    finally:
        slow.kill()
        slow.wait()
    fast = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        assert daemon.finished.wait(60) and daemon.exit_code == 0
    finally:
        fast.terminate()
        fast.wait(10)
    with Store(daemon.config.db, readonly=True) as store:
        attempts = store.attempts(daemon.learning.run_id)
    assert [a.status for a in attempts] == ["lost"] + ["ok"] * 6
    assert attempts[0].theta == attempts[1].theta and attempts[0].seed == attempts[1].seed
    assert attempts[1].episode_id.endswith(".00000.1")  # same request, new episode id
    assert out.getvalue().count("waiting for the agent") == 2


def test_failed_episodes_are_retried_then_the_run_fails(router, agent_factory, daemon_factory):
    agent = agent_factory("bad", always_fault=True)
    daemon = daemon_factory("bad", episodes=5, max_attempts=3)
    assert daemon.finished.wait(30) and daemon.exit_code == EXIT_FAILED
    with Store(daemon.config.db, readonly=True) as store:
        attempts = store.attempts(daemon.learning.run_id)
        run = store.run(daemon.learning.run_id)
    assert [a.status for a in attempts] == ["fault_pdo_timeout"] * 3
    assert [a.attempt for a in attempts] == [0, 1, 2] and {a.idx for a in attempts} == {0}
    assert len({(a.theta, a.seed) for a in attempts}) == 1  # the same request each time
    assert run.status == "failed" and "3 failed attempts" in run.detail
    assert daemon.learning.engine.n_observations == 0  # faults are never told to the learner
    assert len(agent.requests) == 3


def test_an_e_stopped_robot_pauses_the_run_without_failing_it(router, agent_factory, daemon_factory):
    """An episode ended ``stopped`` by an e-stop and refusals ``unavailable`` while it stays engaged
    are no failures: more of them than ``max_attempts`` leave the run paused, not failed; once
    the robot runs again the same request is served and the run finishes; nothing stopped is
    ever told to the learner."""
    out = io.StringIO()
    agent = agent_factory("held", stopped_first=1, unavailable_next=4)
    daemon = daemon_factory("held", out=out, episodes=3, max_attempts=2)
    wait_until(lambda: len(agent.requests) >= 3, 30, what="the held robot asked again")
    assert daemon.learning.status == "paused" and not daemon.finished.is_set()
    assert daemon.finished.wait(60) and daemon.exit_code == 0, out.getvalue()
    with Store(daemon.config.db, readonly=True) as store:
        attempts = store.attempts(daemon.learning.run_id)
        run = store.run(daemon.learning.run_id)
    assert [a.status for a in attempts] == ["stopped"] + ["refused"] * 4 + ["ok"] * 3
    assert len({(a.theta, a.seed) for a in attempts if a.idx == 0}) == 1  # the same request each time
    assert run.status == "finished" and daemon.learning.engine.n_observations == 3
    assert out.getvalue().count("robot held") == 5 and daemon.learning.status == "idle"


def test_refused_parameters_are_redrawn(router, agent_factory, daemon_factory):
    agent_factory("lim", refuse_above=0.9)
    daemon = daemon_factory("lim", episodes=8, theta0=(0.88,), sigma=(0.05,))
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with Store(daemon.config.db, readonly=True) as store:
        attempts = store.attempts(daemon.learning.run_id)
    refused = [a for a in attempts if a.status == "refused"]
    ok = [a for a in attempts if a.ok]
    assert refused and len(ok) == 8
    assert all(a.theta[0] > 0.9 and "invalid_request" in a.detail for a in refused)
    assert all(a.theta[0] <= 0.9 for a in ok)
    for a in refused:  # the same episode is served by a new perturbation of the same mean
        served = next(o for o in ok if o.idx == a.idx)
        assert served.base_theta == a.base_theta and served.theta != a.theta
        assert served.seed == a.seed and served.attempt > a.attempt


def test_an_agent_refusing_everything_fails_the_run(router, agent_factory, daemon_factory):
    agent_factory("nope", refuse_above=-1.0)
    daemon = daemon_factory("nope", episodes=3)
    assert daemon.finished.wait(60) and daemon.exit_code == EXIT_FAILED
    with Store(daemon.config.db, readonly=True) as store:
        assert len(store.attempts(daemon.learning.run_id, "refused")) == MAX_REDRAWS + 1
        assert "refused 21 perturbations" in store.run(daemon.learning.run_id).detail


# --------------------------------------------------------------------------- resume
def _daemon_cmd(router, db: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "ersac_hil.cli", "daemon", "--robot", "res", "--zenoh", router.endpoint,
            "--db", str(db), "--episodes", "14", "--seed", "21", "--kappa", "1.5",
            "--theta0", "0.5", "--sigma", "0.1",  # perturbations reach the agent's refusal above 0.6
            "--backoff", "0.05,0.2", *extra]


def _ok_history(db: Path):
    with Store(db, readonly=True) as store:
        (run,) = store.runs()
        episodes = [(e.idx, e.theta, e.seed, dict(e.cost_terms), e.cost) for e in store.ok_episodes(run.run_id)]
        updates = [(u.idx, u.theta_before, u.theta_after, u.J, u.r, u.kappa) for u in store.updates(run.run_id)]
        return run, episodes, updates, store.attempts(run.run_id)


def test_a_critic_failure_mid_run_skips_updates_and_the_run_finishes(router, agent_factory, daemon_factory):
    """Episode 14 reports body_acc_sq = 1e200: every critic fit over a neighbourhood holding it
    fails. Those updates are skipped with the reason recorded, the run finishes, and the stored
    run can still be rebuilt (the resume path)."""
    agent_factory("sick", huge_cost_at=(14,))
    out = io.StringIO()
    daemon = daemon_factory("sick", episodes=20, out=out)
    assert daemon.finished.wait(60) and daemon.exit_code == 0, out.getvalue()
    with Store(daemon.config.db, readonly=True) as store:
        run = store.run(daemon.learning.run_id)
        updates = store.updates(run.run_id)
        engine = rebuild_engine(store, run)
    assert run.status == "finished" and len(updates) == 20
    skipped = updates[-1].state["skipped_updates"]
    assert skipped and skipped[0][0] == 14 and "critic fit failed" in skipped[0][1]
    for u in updates:
        if u.idx in {i for i, _ in skipped}:
            assert u.theta_after == u.theta_before and u.J is None
    assert "update skipped (critic fit failed" in out.getvalue()
    assert engine.n_observations == 20 and len(engine.propose()[0].theta) == 1


def test_resume_after_sigkill_continues_exactly(router, agent_factory, tmp_path):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    agent_factory("res", delay_s=0.1, fault_every=5, refuse_above=0.6)  # faults and redraws
    reference = tmp_path / "ref.db"
    done = subprocess.run(_daemon_cmd(router, reference), env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr

    killed = tmp_path / "killed.db"
    proc = subprocess.Popen(_daemon_cmd(router, killed), env=env, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        wait_for_store(killed, lambda s, run: len(s.ok_episodes(run)) >= 7 and s.attempts(run, "pending"))
        proc.send_signal(signal.SIGKILL)  # mid-episode: an attempt is pending
        proc.wait(10)
    finally:
        proc.kill()
    first = proc.stdout.read()
    assert "episode    7/14" in first
    resumed = subprocess.run(_daemon_cmd(router, killed), env=env, cwd=ROOT, capture_output=True,
                             text=True, timeout=120)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert "resumed at episode" in resumed.stdout and "interrupted attempt" in resumed.stdout

    ref_run, ref_eps, ref_updates, ref_attempts = _ok_history(reference)
    run, eps, updates, attempts = _ok_history(killed)
    assert any(a.status == "refused" for a in ref_attempts)  # the redraw path was exercised
    assert run.status == "finished" and run.seed == ref_run.seed
    assert [e[0] for e in eps] == list(range(14))  # no episode lost, none duplicated
    assert eps == ref_eps  # same requests (theta, seed), same costs
    assert updates == ref_updates  # identical learning, bit for bit
    interrupted = [a for a in attempts if a.status == "interrupted"]
    assert len(interrupted) == 1
    retry = [a for a in attempts if a.idx == interrupted[0].idx and a.status == "ok"][0]
    assert (retry.theta, retry.seed) == (interrupted[0].theta, interrupted[0].seed)
    assert retry.attempt > interrupted[0].attempt

    # a supervisor restarting the daemon after the end: it says so, exits 0, repeats nothing
    again = subprocess.run(_daemon_cmd(router, killed), env=env, cwd=ROOT, capture_output=True,
                           text=True, timeout=120)
    assert again.returncode == 0 and "already finished" in again.stdout, again.stdout + again.stderr
    with Store(killed, readonly=True) as store:
        assert [r.run_id for r in store.runs()] == [run.run_id]
    assert _ok_history(killed)[1] == eps


def test_sigterm_interrupts_the_episode_and_exits_143(router, agent_factory, tmp_path):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    agent_factory("res", delay_s=60.0)  # an episode that outlasts the test's deadline
    db = tmp_path / "term.db"
    proc = subprocess.Popen(_daemon_cmd(router, db), env=env, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        wait_for_store(db, lambda s, run: s.attempts(run, "pending"))
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)  # exits while the episode runs: cancelled, not waited for
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, out
    with Store(db, readonly=True) as store:
        (run,) = store.runs()
        assert [a.status for a in store.attempts(run.run_id)] == ["interrupted"], out
        assert run.status == "running"  # resumable


@pytest.fixture
def full_disk(tmp_path):
    """A small file system (tmpfs, 64 KiB) mounted for the test, filled to the last byte."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,mode=0755", "tmpfs", str(disk)],
                             capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small file system here: {mounted.stderr.strip()}")
    try:
        with open(disk / "filler", "wb", buffering=0) as filler, pytest.raises(OSError, match="No space left"):
            while True:
                filler.write(bytes(4096))
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_store_that_cannot_be_created_for_lack_of_space_exits_5_and_leaves_nothing(router, full_disk):
    """The session is open, the new store cannot be written (a full disk): not a usage error
    (2) but the store's (5), one line naming the store, and neither the store's file, its
    journals nor the directories made for it are left behind."""
    db = full_disk / "new" / "dir" / "run.db"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(_daemon_cmd(router, db), env=env, cwd=ROOT, capture_output=True, text=True, timeout=120)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == EXIT_STORE, done.stdout + done.stderr
    assert len(lines) == 1 and f"store {db} cannot be created" in lines[0], done.stderr
    assert [p.name for p in full_disk.iterdir()] == ["filler"]


# --------------------------------------------------------------------------- reply source
def test_a_late_answer_to_an_earlier_attempt_is_not_the_answer_of_its_retry(router):
    """How the daemon tells the answer of the request it asked from an answer of before: the
    reply must come to its query, from a session holding the agent's session token, and carry
    the id it asked (``<run>.<idx>.<attempt>``, a new one per attempt). An agent cut off mid-
    episode comes back on the same Zenoh session (the same id, its token declared again), so
    only the request id tells its answer to the cut attempt from the retry's: here that late
    answer arrives in the retry's query, from the agent's own session, and is a bad reply, never
    the retry's result."""
    from ersac_hil.daemon.agents import AgentLink
    from protocol.zenoh import EpisodeRequest, EpisodeResult, get_task

    keys = KeySpace("late")
    terms = synthetic_terms(0.5, 7)
    late = EpisodeResult("20260101T000000-abcdef.00002.0", "bracing", "ok", terms, get_task("bracing").total_cost(terms))
    agent, learner = router.open_client(), router.open_client()
    tokens = [agent.liveliness().declare_token(keys.agent_alive),
              agent.liveliness().declare_token(keys.agent_session(agent.info.zid()))]
    answering = agent.declare_queryable(keys.episode_run, lambda query: query.reply(keys.episode_run, late.to_json()))
    link = AgentLink(learner, keys, 20.0, threading.Event())
    try:
        link.wait_ready(20)
        retry = EpisodeRequest("20260101T000000-abcdef.00002.1", "bracing", (0.5,), 7)
        outcome = link.run(retry)
    finally:
        link.close()
        for entity in (answering, *tokens):
            entity.undeclare()
        learner.close()
        agent.close()
    assert outcome.status == "bad_reply" and outcome.result is None, outcome
    assert outcome.detail == f"reply for {late.episode_id}/bracing, asked {retry.episode_id}/bracing"


def test_a_rogue_episode_queryable_never_feeds_the_learner(router, agent_factory, daemon_factory):
    """A second episode/run queryable answering schema-valid zero costs (the forgery of issue
    11) next to the real agent: the daemon takes only replies from the agent's session."""
    agent_factory("forged", delay_s=0.05)
    agent_factory("forged", rogue=True)  # answers first, with zero costs, holds no token
    daemon = daemon_factory("forged", episodes=4)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with Store(daemon.config.db, readonly=True) as store:
        ok = store.ok_episodes(daemon.learning.run_id)
    assert len(ok) == 4 and all(e.cost_terms["body_acc_sq"] > 0 for e in ok)


def test_replies_only_from_a_session_without_agent_token_are_bad_replies(router, agent_factory,
                                                                          daemon_factory):
    impostor = router.open_client()  # holds the agent's presence tokens for the wrong session
    keys = KeySpace("impostor")
    tokens = [impostor.liveliness().declare_token(keys.agent_alive),
              impostor.liveliness().declare_token(keys.agent_session(impostor.info.zid()))]
    try:
        agent_factory("impostor", rogue=True)
        daemon = daemon_factory("impostor", episodes=2, max_attempts=2)
        assert daemon.finished.wait(60) and daemon.exit_code == EXIT_FAILED
        with Store(daemon.config.db, readonly=True) as store:
            bad = store.attempts(daemon.learning.run_id, "bad_reply")
            assert not store.ok_episodes(daemon.learning.run_id)
        assert len(bad) == 2 and all("not the agent's" in e.detail for e in bad)
    finally:
        for token in tokens:
            token.undeclare()
        impostor.close()


@pytest.mark.parametrize("learner, kappa, selected", [("select", 2.0, True), ("select", 0.0, False),
                                                      ("guarded", 2.0, False)])
def test_the_select_learner_adopts_the_offline_selection_when_the_budget_is_spent(
        router, agent_factory, daemon_factory, learner, kappa, selected):
    name = f"fin{learner}{kappa:g}"
    agent_factory(name)
    daemon = daemon_factory(name, episodes=14, kappa=kappa, learner=learner)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with Store(daemon.config.db, readonly=True) as store:
        run = daemon.learning.run_id
        changes = [c for c in store.changes(run) if c.kind == "theta"]
        ups = store.updates(run)
    assert len(ups) == 14
    if not selected:
        assert changes == []
        return
    (change,) = changes
    assert change.source == "final selection" and change.n_updates == 14
    theta, _, _ = daemon.learning.engine.select(2.0, pessimism=2.0)
    assert list(theta) == change.value == list(daemon.learning.engine.theta)
