"""Bracing for a fall (paper 5.1, Figs. 1-2): the Monte Carlo landscape, paired kappa 2 /
kappa 0 learning runs, the critic along a run and the critic of learning + random policies.

Results (``analyse``): the landscape table and its argmins; per run seed the final theta of
both kappas, the paired differences (kappa 0 minus kappa 2), how many pairs have kappa 2
lower, their median and the one-sided Wilcoxon signed-rank p; how many kappa-2 runs end
within 0.15 of the landscape's argmin of mean + 2 std; damage rates over the last
``last_window`` episodes of every run; Fig. 1 (critic after 5, 15, 35, 45 episodes of the
first kappa-2 run) and Fig. 2 (one VHGP on that run's episodes plus the random policies).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ersac_hil.agent.policies import BracingPolicy

from . import figures, plan
from .plan import Sizes
from .runner import Pool
from .stats import Landscape, paired
from .trials import TrialStore
from .views import critic_curve, engine_after, global_fit, history

__all__ = ["known_trials", "execute", "analyse", "WITHIN"]

#: "kappa 2 within 0.15 of the Monte Carlo argmin of mean + 2 std".
WITHIN = 0.15
TERMS = ("damage", "body_acc_sq", "arm_power")


def known_trials(sizes: Sizes, out: Path) -> list:
    """The trials of the experiment (all known in advance)."""
    return plan.landscape_trials(sizes) + plan.random_policy_trials(sizes)


def execute(pool: Pool, sizes: Sizes, out: Path) -> None:
    """Every learning run (long jobs first), the landscape and the random policies."""
    jobs = pool.learning_jobs(plan.bracing_runs(sizes), out)
    jobs += pool.trial_jobs(plan.landscape_trials(sizes), "landscape")
    jobs += pool.trial_jobs(plan.random_policy_trials(sizes), "random policy")
    pool.run(jobs)


def landscape(sizes: Sizes, trials: TrialStore) -> Landscape:
    thetas = plan.landscape_thetas(sizes)
    specs = plan.landscape_trials(sizes)
    got = trials.get(specs)
    rows = [[got[s] for s in specs if s.theta[0] == t] for t in thetas]
    policy = BracingPolicy()
    return Landscape.from_arrays(
        thetas, [[tr.cost() for tr in row] for row in rows],
        [[tr.failed("hardware_damage") for tr in row] for row in rows],
        [[tr.failed("fallen") for tr in row] for row in rows], TERMS,
        [[[tr.cost_terms[k] for k in TERMS] for tr in row] for row in rows],
        [policy.stiffness(t) for t in thetas])


def analyse(sizes: Sizes, out: Path, trials: TrialStore, say=print) -> dict[str, Any]:  # noqa: ANN001
    """The results section and figures of the bracing experiment (see the module doc)."""
    land = landscape(sizes, trials)
    figures.landscape(land, out / "bracing_landscape.png")
    target = land.theta_min(2.0)
    runs: dict[str, dict[int, Any]] = {f"{k:g}": {} for k in plan.KAPPAS}
    for spec in plan.bracing_runs(sizes):
        runs[f"{spec.kappa:g}"][spec.seed] = history(spec.db(out))
    seeds = sorted(runs["2"])
    final = {k: [float(runs[k][s].final_policy[0]) for s in seeds] for k in runs}
    w = sizes.last_window
    damage = {k: [float(runs[k][s].damage[-w:].mean()) for s in seeds] for k in runs}
    p = paired(final["2"], final["0"])
    within = [abs(t - target) <= WITHIN for t in final["2"]]
    figures.bracing_runs(runs, seeds, target, land.theta_min(0.0), out / "bracing_runs.png")
    fig1 = _fig1(sizes, out, runs["2"][seeds[0]], land)
    fig2 = _fig2(sizes, out, runs["2"][seeds[0]], trials)
    say(f"bracing: kappa 2 lower in {p.n_lower}/{len(seeds)} pairs, median difference "
        f"{p.median_diff:.3f}, Wilcoxon p {p.wilcoxon_p:.4g}; within {WITHIN} of the F2 argmin "
        f"{target:.2f}: {sum(within)}/{len(seeds)}")
    return {
        "landscape": {"rows": land.rows(), **land.summary(), "markdown": land.markdown()},
        "seeds": seeds,
        "final_theta": {f"kappa_{k}": v for k, v in final.items()},
        "paired": {"difference_k0_minus_k2": p.diff.tolist(), "k2_lower": p.n_lower, "pairs": len(seeds),
                   "median_difference": p.median_diff, "wilcoxon_p_one_sided": p.wilcoxon_p},
        "within": {"target_theta": target, "tolerance": WITHIN, "count": int(sum(within)),
                   "per_seed": [bool(x) for x in within]},
        f"damage_rate_last_{w}": {f"kappa_{k}": v for k, v in damage.items()},
        f"damage_rate_last_{w}_mean": {f"kappa_{k}": float(np.mean(v)) for k, v in damage.items()},
        "damage_rate_all_mean": {f"kappa_{k}": float(np.mean([runs[k][s].damage.mean() for s in seeds]))
                                 for k in runs},
        "fig1": fig1, "fig2": fig2,
    }


def _fig1(sizes: Sizes, out: Path, run, land: Landscape) -> dict[str, Any]:  # noqa: ANN001
    """The critic after n episodes of the first kappa-2 run (n in ``fig1_after``)."""
    grid = np.linspace(0.0, 1.0, sizes.grid)
    db = plan.bracing_runs(sizes)[0].db(out)
    panels = []
    for n in sizes.fig1_after:
        n = min(n, run.n)
        J, r = critic_curve(engine_after(db, n), grid) if n >= 1 else (grid * math.nan, grid * math.nan)
        panels.append({"n": n, "J": J, "r": r, "theta": run.theta[:n, 0], "cost": run.cost[:n],
                       "damage": run.damage[:n], "policy": float(run.policy_after(n)[0])})
    figures.fig1(grid, panels, land, out / "fig1_critic.png")
    return {"after": [p["n"] for p in panels], "policy": [p["policy"] for p in panels]}


def _fig2(sizes: Sizes, out: Path, run, trials: TrialStore) -> dict[str, Any]:  # noqa: ANN001
    """One VHGP on the run's learning episodes plus the random policies; the final policy and
    the fit's argmin of J~ + 2 r~."""
    random = [tr for tr in trials.get(plan.random_policy_trials(sizes)).values() if tr.ok]
    x = np.concatenate([run.theta[:, 0], [tr.spec.theta[0] for tr in random]])
    y = np.concatenate([run.cost, [tr.cost() for tr in random]])
    dmg = np.concatenate([run.damage, [tr.failed("hardware_damage") for tr in random]])
    grid = np.linspace(0.0, 1.0, sizes.grid)
    fit = global_fit(x, y, grid)
    final = float(run.theta_after[-1][0]) if len(run.theta_after) else float(run.theta0[0])
    argmin = float(grid[np.nanargmin(fit[0] + 2 * fit[1])]) if fit is not None else math.nan
    figures.fig2(grid, fit, x, y, dmg, len(run.cost), final, argmin, out / "fig2_critic.png")
    return {"points": int(len(x)), "learning": int(run.n), "random": len(random), "final_theta": final,
            "fit_argmin_F2": argmin, "final_minus_argmin": final - argmin}
