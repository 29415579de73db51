"""The progress count of ``reproduce``: the episodes of the experiments asked for, not whatever
else the output directory's trial store holds."""
from __future__ import annotations

from ersac_hil.reproduce.cli import _count
from ersac_hil.reproduce import plan
from ersac_hil.reproduce.plan import QUICK, landscape_trials
from ersac_hil.reproduce.trials import TrialStore


def test_the_count_holds_only_the_experiments_trials(tmp_path):
    with TrialStore(tmp_path / "trials.db") as store:
        store.put(plan.test_trials(plan.initial_theta("lifting"), 1, QUICK)[0], None, "refused", "stored all the same")
        total, count = _count(tmp_path, QUICK, ("bracing",))
        assert count() == 0 and total >= len(landscape_trials(QUICK))
        store.put(landscape_trials(QUICK)[0], None, "refused", "stored all the same")
        assert count() == 1
