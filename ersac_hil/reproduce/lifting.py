"""Dynamic heavy lifting (paper 5.2, Fig. 4): risk-neutral learning from the initial policy,
then test trials of the initial policy and of the policies after 15 and 30 episodes.

Success (a test trial): the episode ran (status ok), the bottle was neither dropped nor did
the robot fall, and at the end the bottle is at the goal height (within the agent's goal
tolerance, 5 cm): "bottle above the shoulder, goal height reached". Per run seed: mean test
cost and success rate per stage, and the one-sided Welch p that the 30-episode policy's mean
test cost is below the initial policy's.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from . import figures, plan
from .plan import Sizes
from .runner import Pool, finished
from .stats import describe, welch
from .trials import Trial, TrialStore
from .views import history

__all__ = ["known_trials", "execute_runs", "execute", "analyse", "stages", "learner", "success"]


def stages(sizes: Sizes) -> tuple[tuple[str, int], ...]:
    """(label, updates) of the tested policies."""
    return (("initial", 0), (f"after {sizes.lifting_stage}", sizes.lifting_stage),
            (f"after {sizes.lifting_episodes}", sizes.lifting_episodes))


def learner(interleave_every: int) -> str:
    """The learner of the lifting runs in words."""
    return (f"interleaved offline search every {interleave_every} updates" if interleave_every
            else "the paper's Algorithm 1")


def success(trial: Trial) -> bool:
    """``Trial.lifted``: the one success criterion of the lifting experiments."""
    return trial.lifted()


def execute_runs(pool: Pool, sizes: Sizes, out: Path, runs=None) -> None:  # noqa: ANN001
    pool.run(pool.learning_jobs(runs or plan.lifting_runs(sizes), out))


def test_specs(sizes: Sizes, out: Path, done_only: bool = False) -> dict[int, list[tuple[str, list]]]:
    """Per run seed: (stage label, test trial specs) of each stage (the runs must be done;
    ``done_only``: of the runs that are done, skipping the others)."""
    specs = {}
    for run in plan.lifting_runs(sizes):
        if done_only and not finished(run, out):
            continue
        h = history(run.db(out))
        specs[run.seed] = [(label, plan.test_trials(tuple(h.policy_after(n)), run.seed, sizes))
                           for label, n in stages(sizes)]
    return specs


def known_trials(sizes: Sizes, out: Path) -> list:
    """The test trials of the runs done so far."""
    return [s for per_seed in test_specs(sizes, out, done_only=True).values() for _, ss in per_seed for s in ss]


def execute(pool: Pool, sizes: Sizes, out: Path) -> None:
    execute_runs(pool, sizes, out)
    specs = [s for per_seed in test_specs(sizes, out).values() for _, ss in per_seed for s in ss]
    pool.run(pool.trial_jobs(specs, "lifting test"))


def analyse(sizes: Sizes, out: Path, trials: TrialStore, say=print) -> dict[str, Any]:  # noqa: ANN001
    per_seed = {}
    columns: dict[int, list[tuple[str, list[Trial]]]] = {}
    for seed, stage_specs in test_specs(sizes, out).items():
        cols = []
        for label, specs in stage_specs:
            got = trials.get(specs)
            cols.append((label, [got[s] for s in specs if s in got]))
        columns[seed] = cols
        costs = {label: [t.cost() for t in ts if t.ok] for label, ts in cols}
        first, last = cols[0][0], cols[-1][0]
        h = history(plan.lifting_runs(sizes)[seed - 1].db(out))
        per_seed[str(seed)] = {
            "theta": {label: list(map(float, h.policy_after(n))) for label, n in stages(sizes)},
            "cost": {label: describe(c) for label, c in costs.items()},
            "success_rate": {label: float(np.mean([success(t) for t in ts])) if ts else float("nan")
                             for label, ts in cols},
            "dropped_rate": {label: float(np.mean([t.failed("bottle_dropped") for t in ts])) if ts else float("nan")
                             for label, ts in cols},
            "welch_p_initial_vs_last": welch(costs[first], costs[last]),
            "learning_cost": h.cost.tolist(),
        }
    figures.fig4(columns, success, out / "fig4_lifting.png")
    figures.learning_curves({s: history(r.db(out)) for s, r in
                             ((r.seed, r) for r in plan.lifting_runs(sizes))}, out / "lifting_learning.png")
    labels = [label for label, _ in stages(sizes)]
    last = labels[-1]
    improved = [s for s, r in per_seed.items()
                if r["cost"][last]["mean"] < r["cost"]["initial"]["mean"] and r["welch_p_initial_vs_last"] < 0.01]
    pooled = {label: float(np.mean([success(t) for cols in columns.values() for lab, ts in cols if lab == label
                                    for t in ts])) for label in labels}
    say(f"lifting ({learner(sizes.lifting_interleave_every)}): {len(improved)}/{len(per_seed)} seeds improve with Welch p < 0.01; success "
        + ", ".join(f"{k} {100 * v:.0f} %" for k, v in pooled.items()))
    return {"stages": labels, "interleave_every": sizes.lifting_interleave_every,
            "learner": learner(sizes.lifting_interleave_every), "per_seed": per_seed, "seeds_improved_p01": len(improved),
            "seeds": len(per_seed), "success_rate_pooled": pooled,
            "success_rate_last_per_seed": [r["success_rate"][last] for r in per_seed.values()]}
