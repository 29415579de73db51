"""A simulator prior from a simulator the robot does not match: the robot is the firmware
simulator with weak elbow cables (``sim --physics``: 820 N instead of 960 N, so the catch of
the prior's kappa-2 optimum, ~850 N peak at theta 0.35, breaks them), the prior the landscape
of the model's own physics (docs/reproduce.md). Through every real process (router,
simulator, agent, one ``ersac-hil daemon --prior``): the run starts at the prior's optimum,
drops the prior after the warm-up and recovers on the softer side."""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from ersac_hil.daemon.store import Store
from ersac_hil.reproduce.runner import Pool, RunSpec, physics_stack
from ersac_hil.reproduce.trials import TrialStore
from ersac_hil.reproduce.views import history

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

#: theta, mean and std of the model's bracing landscape (100 seeds per theta, docs/reproduce.md)
MODEL = ([0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65, 0.70],
         [198.4, 190.3, 182.1, 177.6, 175.0, 175.0, 173.5, 169.6, 165.9, 162.5, 164.0],
         [6.3, 5.5, 5.9, 7.6, 9.9, 16.1, 23.4, 29.9, 34.5, 39.5, 46.6])


def test_a_prior_from_a_wrong_simulator_is_dropped_and_the_run_recovers(tmp_path):
    prior = tmp_path / "model-landscape.json"
    prior.write_text(json.dumps({"rows": [{"theta": t, "mean": m, "std": s} for t, m, s in zip(*MODEL)]}))
    physics = tmp_path / "weak-cables.toml"
    physics.write_text("[cable]\nbreaking_tension = 820.0\n")
    stop = threading.Event()
    stack = physics_stack(tmp_path / "logs", stop, print, physics)
    trials = TrialStore(tmp_path / "trials.db")
    pool = Pool(stack, trials, stop, print)
    spec = RunSpec("prior-k2", "bracing", 2.0, 3, 22, ("--prior", str(prior), "--learner", "guarded"))
    try:
        pool.run(pool.learning_jobs([spec], tmp_path))
    finally:
        pool.close()
        stack.close()
        trials.close()
    h = history(spec.db(tmp_path))
    assert h.run.settings["theta0"] == [0.35]  # the model's optimum of mean + 2 std
    with Store(spec.db(tmp_path), readonly=True) as store:
        (rejected,) = [c for c in store.changes(h.run.run_id) if c.source.startswith("prior rejected")]
    assert rejected.n_updates == 10 and rejected.value == [0.2]
    # the warm-up around 0.35 broke cables; after it the run learns on the softer side, where
    # this robot's cables hold
    warm, after = h.damage[:10], h.damage[12:]
    assert warm.mean() >= 0.5 and after.mean() < warm.mean()
    assert float(h.final_policy[0]) < 0.35 and np.all(h.theta_after[10:, 0] < 0.35)
