"""The trial store: a trial is its request (task, theta, seed); stored once, read back exactly,
kept across reopening (resume)."""
from __future__ import annotations

import pytest

from ersac_hil.reproduce.trials import Trial, TrialSpec, TrialStore
from protocol.zenoh import EpisodeResult, InvalidField, get_task


def _result(terms) -> EpisodeResult:
    spec = get_task("bracing")
    return EpisodeResult(episode_id="e1", task="bracing", status="ok", cost_terms=terms,
                         total_cost=spec.total_cost(terms),
                         failures={"hardware_damage": True, "over_current": False, "fallen": False,
                                   "bottle_dropped": False},
                         duration_s=2.0, wall_s=0.7, telemetry={"n_cycles": 400.0}, fault_counts={}, detail="")


def test_trials_are_stored_once_by_content_and_survive_reopening(tmp_path):
    a, b = TrialSpec("bracing", (0.25,), 3), TrialSpec("bracing", (0.25,), 4)
    terms = {"damage": 1.0, "body_acc_sq": 600.0, "arm_power": 20.0}
    with TrialStore(tmp_path / "t.db") as store:
        assert store.missing([a, b, TrialSpec("bracing", [0.25], 3)]) == [a, b]  # duplicates once
        store.put(a, _result(terms), "ok")
        store.put(b, None, "refused", "invalid_request: no")
        assert store.missing([a, b]) == [] and store.count() == 2
    with TrialStore(tmp_path / "t.db") as store:
        got = store.get([a, b, TrialSpec("bracing", (0.5,), 3)])
    assert set(got) == {a, b}
    trial: Trial = got[a]
    assert trial.ok and trial.failed("hardware_damage") and dict(trial.cost_terms) == terms
    assert trial.cost() == pytest.approx(10 + 60 + 100) and trial.cost({"damage": 0.0}) == pytest.approx(160)
    assert not got[b].ok and got[b].cost_terms == {}


def test_a_trial_outside_the_task_box_is_refused_at_once():
    with pytest.raises(InvalidField):
        TrialSpec("bracing", (1.5,), 0)
    with pytest.raises(InvalidField):
        TrialSpec("lifting", (0.5,), 0)
