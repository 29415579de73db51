"""``ersac-hil daemon --prior PATH``: the run starts from the simulated optimum for its kappa,
with the simulated landscape as its critic's prior mean, and a prior the robot's warm-up
episodes disagree with is dropped, critic prior included (the run goes on from the task's
default start and recovers)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.daemon.config import ConfigError, DaemonConfig, load_toml, merge
from ersac_hil.daemon.prior import PriorError, load_prior
from ersac_hil.daemon.runs import rebuild_engine
from ersac_hil.daemon.store import Store
from ersac_hil.learner.prior import SimPrior
from ersac_hil.reproduce.views import history
from helpers.synthetic_agent import true_cost

ROOT = Path(__file__).resolve().parents[3]
GRID = np.round(np.arange(0.0, 1.0001, 0.05), 2)


def landscape(path, mean_std):  # noqa: ANN001
    rows = [{"theta": float(t), "mean": m, "std": s} for t, (m, s) in zip(GRID, map(mean_std, GRID))]
    path.write_text(json.dumps({"rows": rows}))
    return path


#: The range of the final F2 of one 30-episode guarded run without a prior (kappa 2) over run
#: seeds 1-12: 7.45-10.03. A run with the wrong prior, after its rejection, ends within it
#: (7.43-9.90; seed for seed -2.3 to +2.2 off the run without the prior: two runs' last points
#: differ by up to this much from the noise of 20 episodes alone).
ONE_RUN_SPREAD_F2 = 2.6


def F2(theta: float) -> float:
    m, s = true_cost(theta)
    return m + 2 * s


def test_a_landscape_prior_gives_the_argmin_of_mean_plus_kappa_std(tmp_path):
    f = landscape(tmp_path / "l.json", true_cost)
    weights = {"damage": 10.0, "body_acc_sq": 0.1, "arm_power": 5.0}
    for kappa in (0.0, 2.0):
        p = load_prior(f, "bracing", kappa, weights)
        best = GRID[np.argmin([true_cost(t)[0] + kappa * true_cost(t)[1] for t in GRID])]
        assert p.theta == (best,) and p.kappa == kappa


@pytest.mark.parametrize("text, says", [
    (None, "no such file"), ("{}", "no landscape rows"), ("[1, 2", "JSONDecodeError"),
    ('{"rows": [{"theta": 0.1}]}', "KeyError"),
])
def test_a_bad_prior_is_refused_in_one_line_naming_it(tmp_path, text, says):
    f = tmp_path / "p.json"
    if text is not None:
        f.write_text(text)
    with pytest.raises(ConfigError, match=f"prior.*{says}"):
        merge({}, {"robot": "r", "prior": str(f)})


def test_prior_use_is_one_option_over_the_prior(tmp_path):
    f = landscape(tmp_path / "l.json", true_cost)
    assert merge({}, {"robot": "r", "prior": str(f)}).prior_use == "start"
    assert merge({}, {"robot": "r", "prior": str(f), "prior_use": "critic"}).prior_use == "critic"
    toml = tmp_path / "d.toml"
    toml.write_text(f'robot = "r"\nprior = "{f}"\nprior_use = "critic"\n')
    assert merge(load_toml(toml), {}).prior_use == "critic"
    with pytest.raises(ConfigError, match="prior_use.*needs a prior"):
        merge({}, {"robot": "r", "prior_use": "critic"})
    with pytest.raises(ConfigError, match="prior_use"):
        merge({}, {"robot": "r", "prior": str(f), "prior_use": "both"})


def test_the_old_spelling_is_refused_with_the_new_one(tmp_path):
    f = landscape(tmp_path / "l.json", true_cost)
    toml = tmp_path / "old.toml"
    toml.write_text(f'robot = "r"\nprior = "{f}"\nprior_critic = true\n')
    with pytest.raises(ConfigError, match='prior_critic was renamed: use prior_use = "critic"'):
        load_toml(toml)
    done = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "daemon", "--robot", "u", "--prior", str(f),
                           "--prior-critic", "--db", str(tmp_path / "x.db")], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--prior-critic was renamed: use --prior-use critic" in done.stderr
    assert not (tmp_path / "x.db").exists()


@settings(max_examples=50, deadline=None)
@given(st.floats(1.0, 100.0), st.floats(0.1, 10.0), st.integers(0, 2**32 - 1))
def test_costs_drawn_as_the_simulator_says_are_consistent_far_off_ones_are_not(mean, std, seed):
    rng = np.random.default_rng(seed)
    p = SimPrior((0.3,), mean, std, 2.0, "test")
    # a robot drawing as the simulator says passes (Z = 3: rarely refused; a fixed seed set here)
    same = rng.normal(mean, std, 10)
    shifted = same + 3 * std + 0.2 * mean
    wider = mean + (same - mean) * 5
    assert not p.consistent(shifted)[0]
    assert not p.consistent(wider)[0] or abs(np.std(wider, ddof=1)) <= 2 * std
    if abs(same.mean() - mean) <= 2 * std / np.sqrt(10) and np.std(same, ddof=1) <= 1.8 * std:
        assert p.consistent(same)[0]


def jump_costs(rng, n: int, damaged: np.ndarray, base: float = 176.7, spread: float = 4.0, jump: float = 90.0):
    """Bracing-shaped warm-up costs: a normal base and a jump for every damaged episode."""
    return base + spread * rng.standard_normal(n) + jump * damaged


def test_one_broken_cable_in_the_warm_up_keeps_a_right_prior_when_damage_is_judged_apart():
    # the simulator at the bracing kappa-2 optimum 0.35: mean 177.6, std 7.6 (mostly the 1 %
    # of damaged episodes, +90 each, on a spread of 4), damage rate 0.01
    p = SimPrior((0.35,), 177.6, 7.6, 2.0, "landscape", damage=0.01)
    rng = np.random.default_rng(3)
    hit = np.zeros(10, dtype=bool)
    hit[4] = True
    costs = jump_costs(rng, 10, hit)
    ok, why = p.consistent(costs, hit)
    assert ok and "1 of 10 damaged" in why, why
    # a mean and spread over all costs take the one jump for a robot 3x noisier than simulated
    ok, why = p.consistent(costs)
    assert not ok and "spread" in why


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10), st.floats(0.0, 0.5), st.integers(0, 2**32 - 1))
def test_the_damage_count_is_judged_by_its_binomial_tails(k, rate, seed):
    from scipy.stats import binom

    from ersac_hil.learner.prior import DAMAGE_ALPHA, DAMAGE_FLOOR
    p = SimPrior((0.35,), 177.6, 7.6, 2.0, "landscape", damage=rate)
    rng = np.random.default_rng(seed)
    hit = np.arange(10) < k
    costs = jump_costs(rng, 10, hit, base=177.6)
    ok, why = p.consistent(costs, hit)
    q = max(rate, DAMAGE_FLOOR)
    tails = min(binom.sf(k - 1, 10, q), binom.cdf(k, 10, q))
    if tails < DAMAGE_ALPHA:
        assert not ok and f"damaged {k} of 10" in why
    else:  # decided on the undamaged costs alone, as a mean and spread
        assert ok == p.consistent(costs[~hit])[0] and f"{k} of 10 damaged" in why


def test_a_robot_that_breaks_far_more_often_rejects_the_prior_by_the_count():
    p = SimPrior((0.35,), 177.6, 7.6, 2.0, "landscape", damage=0.01)
    hit = np.array([True, False, True, False, False, True, False, False, False, False])
    ok, why = p.consistent(jump_costs(np.random.default_rng(0), 10, hit), hit)
    assert not ok and "damaged 3 of 10" in why
    with pytest.raises(ValueError, match="flags"):
        p.consistent([1.0, 2.0], [True])


def test_a_landscape_with_a_damage_rate_gives_it_to_the_prior(tmp_path):
    rows = [{"theta": float(t), "mean": m, "std": s, "damage": 0.02 * i}
            for i, (t, (m, s)) in enumerate(zip(GRID, map(true_cost, GRID)))]
    f = tmp_path / "d.json"
    f.write_text(json.dumps({"rows": rows}))
    weights = {"damage": 10.0, "body_acc_sq": 0.1, "arm_power": 5.0}
    p = load_prior(f, "bracing", 2.0, weights)
    i = int(np.argmin([F2(t) for t in GRID]))
    assert p.damage == rows[i]["damage"] and SimPrior.from_dict(p.to_dict()) == p
    assert load_prior(landscape(tmp_path / "l.json", true_cost), "bracing", 2.0, weights).damage is None
    old = {k: v for k, v in p.to_dict().items() if k != "damage"}  # a run stored before the rate
    assert SimPrior.from_dict(old).damage is None


def test_a_right_prior_starts_the_run_at_the_simulated_optimum(router, agent_factory, daemon_factory, tmp_path):
    """With --prior-use critic the landscape is also the critic's prior mean."""
    f = landscape(tmp_path / "l.json", true_cost)
    agent_factory("pri")
    daemon = daemon_factory("pri", episodes=14, kappa=2.0, prior=str(f), prior_use="critic")
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    h = history(daemon.config.db)
    best = GRID[np.argmin([F2(t) for t in GRID])]
    assert h.run.settings["theta0"] == [best] and h.run.settings["prior"]["theta"] == [best]
    assert not [c for c in h.changes if c[0] == "theta" and "prior" in str(c)]
    with Store(daemon.config.db, readonly=True) as store:
        assert not [c for c in store.changes(h.run.run_id) if c.source.startswith("prior rejected")]
        states = [u.state for u in store.updates(h.run.run_id)]
        engine = rebuild_engine(store, store.runs()[-1])
    # the landscape is the critic's prior mean from the first update to the last, and after resume
    assert h.run.settings["prior"]["landscape"][0] == [0.0, *true_cost(0.0)]
    assert all(st["critic"]["prior"]["theta"] == list(GRID) for st in states)
    assert engine._learner.critic_prior is not None


def test_a_wrong_prior_is_dropped_after_the_warm_up_and_the_run_recovers(router, agent_factory, daemon_factory,
                                                                          tmp_path):
    # a simulator that believes stiff arms are safe and cheap: its optimum at 1.0
    wrong = landscape(tmp_path / "wrong.json", lambda t: (8.0 - 4.0 * t, 0.3))
    agent_factory("wro")
    agent_factory("nop")
    with_prior = daemon_factory("wro", episodes=30, kappa=2.0, prior=str(wrong), learner="guarded", prior_use="critic")
    without = daemon_factory("nop", episodes=30, kappa=2.0, learner="guarded")
    assert with_prior.finished.wait(120) and without.finished.wait(120)
    assert with_prior.exit_code == 0 == without.exit_code
    h, h0 = history(with_prior.config.db), history(without.config.db)
    assert h.run.settings["theta0"] == [1.0]
    with Store(with_prior.config.db, readonly=True) as store:
        (rejected,) = [c for c in store.changes(h.run.run_id) if c.source.startswith("prior rejected")]
        assert rejected.n_updates == 10 and rejected.value == [0.2]
        states = [u.state for u in store.updates(h.run.run_id)]
        engine = rebuild_engine(store, store.runs()[-1])
    # the critic's prior went with the rejection: robot episodes only from the 11th update on
    assert "prior" in states[9]["critic"] and not any("prior" in st["critic"] for st in states[10:])
    assert engine._learner.critic_prior is None
    # from there it learns like a run without the prior: it leaves the wrong optimum and ends
    # no worse than the run without it by more than the spread of one run's final F2 (F2 in
    # units of the synthetic cost: ~7.4-19 over the box; the final point of one run is chaotic
    # in the last bits of the arithmetic, e.g. the BLAS kernels of the processor)
    assert F2(float(h.final_policy[0])) <= F2(float(h0.final_policy[0])) + ONE_RUN_SPREAD_F2


def test_by_default_the_prior_gives_the_start_only(router, agent_factory, daemon_factory, tmp_path):
    f = landscape(tmp_path / "l.json", true_cost)
    agent_factory("sta")
    daemon = daemon_factory("sta", episodes=12, kappa=2.0, prior=str(f))
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    h = history(daemon.config.db)
    assert "landscape" not in h.run.settings["prior"]
    with Store(daemon.config.db, readonly=True) as store:
        assert not any("prior" in u.state["critic"] for u in store.updates(h.run.run_id))


def test_the_daemon_judges_the_warm_ups_damage_apart_from_its_cost(router, agent_factory, daemon_factory, tmp_path):
    """The daemon hands the check each warm-up episode's damage (its ``damage`` term above 0):
    a simulator whose costs are right but which says every episode breaks a cable is rejected
    by the damage count (with the costs alone it would pass)."""
    rows = [{"theta": float(t), "mean": m, "std": s, "damage": 1.0} for t, (m, s) in zip(GRID, map(true_cost, GRID))]
    f = tmp_path / "l.json"
    f.write_text(json.dumps({"rows": rows}))
    agent_factory("dmg")
    daemon = daemon_factory("dmg", episodes=12, kappa=2.0, prior=str(f))
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    h = history(daemon.config.db)
    assert h.run.settings["prior"]["damage"] == 1.0
    with Store(daemon.config.db, readonly=True) as store:
        (rejected,) = [c for c in store.changes(h.run.run_id) if c.source.startswith("prior rejected")]
    assert "robot damaged" in rejected.source and "simulated rate of 1" in rejected.source
