"""Learners on the real tasks through the real stack (prints figures; not a test).

    .venv/bin/python bench/tasks.py learning --task bracing --kappas 2,0 --seeds 1-20 \
        --methods default,paper --out bench-tasks
    .venv/bin/python bench/tasks.py learning --task lifting --seeds 1-20 --out bench-tasks
    .venv/bin/python bench/tasks.py peers --seeds 1-20 --pairs 2 --out bench-tasks
    .venv/bin/python bench/tasks.py surrogate --seeds 0-19
    .venv/bin/python bench/tasks.py gaps --seeds 0-9 --out gaps.json
    .venv/bin/python bench/tasks.py kappa0

Every episode is an ``episode/run`` query to an agent of a simulator/agent pair started as in
``ersac-hil reproduce`` (``ersac_hil.demo.Stack``, one pair by default: the machine's cores
are shared); every ERSAC learning run is an ``ersac-hil daemon`` process with its own store
(``ersac_hil.reproduce.runner.Pool``), so what is measured is what a user runs. The output
directory is resumable: a finished run or a stored trial is never run again.

``learning``: ERSAC runs, one per (method, kappa, run seed); a method is a set of daemon
flags (``METHODS``). Bracing: final theta per run; runs within ``TOLERANCE`` of the mean +
kappa std optimum of the Monte Carlo landscape (``LANDSCAPE``, 100 scenario seeds per theta
through the stack, docs/reproduce.md; or ``--landscape FILE``, a ``bench/bracing_sweep.py
--out`` ``landscape.json``); the damage rate of the final policies read off that landscape
(linear between its grid points) against the optimum's; damage over each run's last 15
episodes. Lifting: 10 test trials of the policy after 30 episodes per run (the scenario
seeds of ``reproduce lifting``), success as there.

``surrogate``: the same learners in-process on a cost drawn from the landscape (a damage
Bernoulli of the landscape's rate, ``DAMAGE_COST`` each, on a normal base whose spread makes
up the landscape's std; a fall below theta 0.2): seconds per run instead of a minute, for
screening settings before measuring them through the stack. Per method and kappa: the final
policy as its preset makes it, the last iterate, the offline selection at every kappa and the
mean of the last 10 policies (within ``TOLERANCE`` of the optimum), the damage rate of the
final policies, CPU time; ``--out``: every run with its path.

``peers``: CMA-ES (pycma; each candidate re-evaluated ``REPEATS`` times, bench/learner.py's
constant, scored mean + kappa std), mean-variance Bayesian optimisation in the style of RAHBO
(GPs on the mean and on the log variance of ``REPEATS`` evaluations per point, lower
confidence bound of mean + kappa std) and random search with re-evaluation (bench/learner.py's
implementations), at equal episode budgets on the same stack (every evaluation an independent
episode with the scenario seed the daemon would give the learner's episode of the same index),
against the default learner's runs of the same seeds, at the task's kappa and budget
(``PEER_TASKS``). ``--task bracing``: F(theta, 2) regret of the recommended policy after 15,
30, 45 episodes (against the landscape, interpolated); writes ``tasks.png``. ``--task
lifting``: success of the policy recommended after 30 episodes over the test trials of
``learning --task lifting`` (the same scenario seeds per run seed, ``ersac_hil.reproduce.
lifting.success``); writes ``tasks-lifting.png``. Jobs go seed by seed, so an interrupted
bench leaves a prefix of the seeds for every method; ``--report-only`` prints the tables of
what is stored (complete seeds per method) without running an episode. ``--with-prior``
(bracing): also the default learner with ``--prior`` (the landscape as a JSON).

``gaps``: the simulator prior on surrogate robots that differ from the simulator (``GAPS``:
the landscape's damage rate moved in theta, the undamaged cost scaled; the simulator is the
landscape), kappa 2, the default bracing learner in-process as the daemon runs it (the prior's
start, its consistency check after the warm-up - given the episodes' damage flags and the
landscape's damage rate -, the final selection): episodes until F(theta, 2) of the policy
stays within 5 % of the robot's optimum, damage events while learning, for no prior, the
prior's start only, the start with the critic's prior mean, and ``--methods`` other ways of
moving while that prior is kept (``GAP_METHODS``). Resumable (``--out``'s ``.runs.jsonl``).

``kappa0``: why kappa 0 runs end short of the mean's argmin (computed in seconds): how well
the landscape's episodes locate the argmin, and the expected path of the paper's rule.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from ersac_hil.reproduce import plan  # noqa: E402
from ersac_hil.reproduce.lifting import success  # noqa: E402
from ersac_hil.reproduce.runner import Pool, RunSpec, finished, physics_stack  # noqa: E402
from ersac_hil.reproduce.trials import TrialSpec, TrialStore  # noqa: E402
from ersac_hil.reproduce.views import history  # noqa: E402

#: The bracing landscape through the stack, 100 scenario seeds per theta (docs/reproduce.md):
#: theta, mean J, std J, damage rate.
LANDSCAPE = {
    "theta": [0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95, 1.00],
    "mean": [198.4, 190.3, 182.1, 177.6, 175.0, 175.0, 173.5, 169.6, 165.9, 162.5, 164.0, 167.7, 190.1, 219.7,
             242.8, 250.3, 244.5],
    "std": [6.3, 5.5, 5.9, 7.6, 9.9, 16.1, 23.4, 29.9, 34.5, 39.5, 46.6, 52.5, 57.4, 47.9, 24.7, 18.8, 18.8],
    "damage": [0, 0, 0, 0.01, 0.02, 0.08, 0.13, 0.18, 0.19, 0.20, 0.28, 0.34, 0.59, 0.83, 0.98, 1.00, 1.00],
}
#: "final theta within 0.1 of the optimum".
TOLERANCE = 0.1
#: Named ERSAC settings: extra ``ersac-hil daemon`` flags (docs/learner.md, "The default").
METHODS: dict[str, tuple[str, ...]] = {
    "default": (),
    "paper": ("--learner", "paper"),
    "guarded": ("--learner", "guarded"),
    "select": ("--learner", "select"),
    "trust": ("--learner", "trust"),
    "prior": (),  # the default learner with --prior <the landscape> (prior_flags)
}
#: Cost of a damaged episode in the surrogate (the task's damage weight 10 x the broken arm's
#: extra terms; sized so that mean and std of the landscape are both matched at 0.5-0.75).
DAMAGE_COST = 90.0
#: Learner settings screened in-process (``surrogate``): ERSAC keyword arguments (``greedy``:
#: ``GreedyRule`` fields; ``theta0``: another start; ``sigma``: another sigma), and whether the final policy is the
#: offline selection at a kappa > 0 (the ``select`` preset's final step). Every run also
#: reports the offline selection at every kappa (column "selection at every kappa").
SURROGATE: dict[str, tuple[dict, bool]] = {
    "paper": ({"max_step": None}, False),
    "guarded": ({}, False),
    "guarded+final-selection": ({}, True),
    "interleaved": ({"interleave_every": 1}, False),
    "select": ({"interleave_every": 1}, True),
    # the interleaved search without its confidence gate (z 0) or with a 1-sd gate
    "select-z0": ({"interleave_every": 1, "greedy": {"z": 0.0}}, True),
    "select-z1": ({"interleave_every": 1, "greedy": {"z": 1.0}}, True),
    # a trust-region step along F~: the argmin of F~ within R sigma of theta, every update
    "trust-1": ({"interleave_every": 1, "greedy": {"z": 0.0, "radius": 1.0, "min_move": 0.0, "around": "theta"}}, True),
    "trust-2": ({"interleave_every": 1, "greedy": {"z": 0.0, "radius": 2.0, "min_move": 0.0, "around": "theta"}}, True),
    "trust-1-z1": ({"interleave_every": 1, "greedy": {"z": 1.0, "radius": 1.0, "min_move": 0.0, "around": "theta"}}, True),
    "trust-3": ({"interleave_every": 1, "greedy": {"z": 0.0, "radius": 3.0, "min_move": 0.0, "around": "theta"}}, True),
    "select-start-0.5": ({"interleave_every": 1, "theta0": 0.5}, True),
    "trust-2-start-0.5": ({"interleave_every": 1, "theta0": 0.5,
                           "greedy": {"z": 0.0, "radius": 2.0, "min_move": 0.0, "around": "theta"}}, True),
    # not the paper's sigma (0.05): is exploration what limits kappa 0?
    "select-sigma-0.075": ({"interleave_every": 1, "sigma": 0.075}, True),
    "trust-2-sigma-0.075": ({"interleave_every": 1, "sigma": 0.075,
                             "greedy": {"z": 0.0, "radius": 2.0, "min_move": 0.0, "around": "theta"}}, True),
    "select-sigma-0.1": ({"interleave_every": 1, "sigma": 0.1}, True),
}


@dataclass(frozen=True)
class Landscape:
    theta: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    damage: np.ndarray

    @classmethod
    def load(cls, path: str | None) -> Landscape:
        if path is None:
            d = LANDSCAPE
        else:
            raw = json.loads(Path(path).read_text())
            rows = raw["rows"] if "rows" in raw else raw["landscape"]["rows"]
            d = {"theta": [r["theta"] for r in rows], "mean": [r["mean"] for r in rows],
                 "std": [r["std"] for r in rows], "damage": [r["damage"] for r in rows]}
        return cls(*(np.asarray(d[k], dtype=float) for k in ("theta", "mean", "std", "damage")))

    def F(self, theta: float, kappa: float) -> float:
        return float(np.interp(theta, self.theta, self.mean + kappa * self.std))

    def optimum(self, kappa: float) -> float:
        return float(self.theta[np.argmin(self.mean + kappa * self.std)])

    def damage_at(self, theta: float) -> float:
        return float(np.interp(theta, self.theta, self.damage))


def parse_seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def _stack(out: Path, stop: threading.Event, pairs: int, physics: str | None = None):  # noqa: ANN202
    """The pairs' stack; with ``physics`` every simulator runs with ``--physics FILE``."""
    return physics_stack(out / "logs", stop, lambda line: print(f"tasks: {line}", flush=True),
                         None if physics is None else Path(physics), pairs=pairs)


def prior_flags(out: Path, landscape: str | None) -> tuple[str, ...]:
    """``--prior`` with the landscape (``landscape`` or ``LANDSCAPE``) as a JSON file in ``out``:
    the simulator prior of the stack's own simulator (no reality gap)."""
    land = Landscape.load(landscape)
    path = out / "sim-landscape.json"
    path.write_text(json.dumps({"rows": [{"theta": float(t), "mean": float(m), "std": float(s), "damage": float(d)}
                                         for t, m, s, d in zip(land.theta, land.mean, land.std, land.damage)]}))
    return ("--prior", str(path))


def run_spec(method: str, task: str, kappa: float, seed: int, episodes: int,
             flags: Sequence[str] = ()) -> RunSpec:
    return RunSpec(f"{method}-{task}-k{kappa:g}-s{seed}", task, kappa, seed, episodes, (*METHODS.get(method, ()), *flags))


def learning(args: argparse.Namespace) -> dict:
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    stop = threading.Event()
    seeds = parse_seeds(args.seeds)
    kappas = [float(k) for k in args.kappas.split(",")] if args.task == "bracing" else [0.0]
    episodes = args.episodes or (45 if args.task == "bracing" else 30)
    methods = args.methods.split(",")
    flags = {m: prior_flags(out, args.landscape) if m == "prior" else () for m in methods}
    specs = [run_spec(m, args.task, k, s, episodes, flags[m]) for m in methods for k in kappas for s in seeds]
    stack = _stack(out, stop, args.pairs, args.physics)
    trials = TrialStore(out / "trials.db")
    pool = Pool(stack, trials, stop, lambda line: print(line, flush=True))
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    tests = plan.FULL.test_trials if args.task == "lifting" else 0
    try:
        pool.run([j for spec in specs for j in learner_jobs(pool, spec, out, tests)])
    finally:
        pool.close()
        stack.close()
    wall = time.monotonic() - t0
    print(f"\n{len(specs)} runs, wall time {wall / 60:.1f} min, load average {load0:.1f} -> {os.getloadavg()[0]:.1f}")
    result = {"task": args.task, "seeds": seeds, "wall_s": wall, "runs": {}}
    land = Landscape.load(args.landscape)
    for m in methods:
        for k in kappas:
            dbs = [run_spec(m, args.task, k, s, episodes).db(out) for s in seeds]
            rows = [(s, history(db)) for s, db in zip(seeds, dbs)]
            if args.task == "bracing":
                result["runs"][f"{m} k{k:g}"] = _bracing_table(m, k, rows, land, dbs)
            else:
                result["runs"][f"{m} k{k:g}"] = _lifting_table(m, rows, trials)
    (out / f"learning-{args.task}.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def final_policy(db: Path) -> np.ndarray:
    """The run's final policy under the current code: the ``select`` learner's final step
    recomputed from the store (a pure function of the stored run; a run made before that step
    changed gets today's), else the recorded one (``History.final_policy``)."""
    from ersac_hil.daemon.runs import rebuild_engine
    from ersac_hil.daemon.store import Store
    from ersac_hil.learner.presets import LEGACY_LEARNER, preset

    h = history(db)
    kappa = float(h.run.settings["kappa"])
    if not preset(h.run.settings.get("learner", LEGACY_LEARNER)).final_selection or kappa <= 0:
        return h.policy_after(len(h.theta_after))
    with Store(db, readonly=True) as store:
        engine = rebuild_engine(store, store.runs()[-1])
    engine.adopt(tuple(h.policy_after(len(h.theta_after))))
    return np.asarray(engine.select(kappa, pessimism=kappa)[0], dtype=float)


def _bracing_table(method: str, kappa: float, rows: list, land: Landscape, dbs: list[Path]) -> dict:
    opt = land.optimum(kappa)
    final = [float(final_policy(db)[0]) for db in dbs]
    within = [abs(t - opt) <= TOLERANCE + 1e-9 for t in final]
    dmg = [land.damage_at(t) for t in final]
    last = [float(h.damage[-15:].mean()) for _, h in rows]
    print(f"\nbracing, {method}, kappa {kappa:g}: optimum {opt:.2f} (mean + {kappa:g} std, landscape); "
          f"final theta within {TOLERANCE} in {sum(within)}/{len(rows)}")
    print("| run seed | " + " | ".join(str(s) for s, _ in rows) + " |")
    print("|---" * (len(rows) + 1) + "|")
    print("| final theta | " + " | ".join(f"{'**' if not w else ''}{t:.3f}{'**' if not w else ''}"
                                          for t, w in zip(final, within)) + " |")
    print(f"final theta median {np.median(final):.3f} [{np.percentile(final, 25):.3f}-{np.percentile(final, 75):.3f}]; "
          f"damage rate of the final policies (landscape) {np.mean(dmg):.3f} against {land.damage_at(opt):.3f} at "
          f"the optimum; F(theta, {kappa:g}) regret median {np.median([land.F(t, kappa) - land.F(opt, kappa) for t in final]):.1f}; "
          f"damage over the last 15 episodes {np.mean(last):.3f}; damage while learning {np.mean([h.damage.mean() for _, h in rows]):.3f}")
    return {"optimum": opt, "final_theta": final, "within": int(sum(within)), "damage_final_policy": float(np.mean(dmg)),
            "damage_optimum": land.damage_at(opt), "damage_last_15": float(np.mean(last)),
            "damage_learning": float(np.mean([h.damage.mean() for _, h in rows]))}


def _lifting_table(method: str, rows: list, trials: TrialStore) -> dict:
    rates = [success_rate(trials, h.final_policy, s) for s, h in rows]
    print(f"\nlifting, {method}: success of the policy after {rows[0][1].n} episodes (10 test trials each): "
          f"pooled {100 * np.nanmean(rates):.1f} %; per seed " + ", ".join(f"{s}: {100 * r:.0f}" for (s, _), r in zip(rows, rates)))
    return {"success_per_seed": rates, "success_pooled": float(np.nanmean(rates))}


def surrogate_episode(theta: float, land: Landscape, rng: np.random.Generator) -> tuple[float, bool]:
    """One episode's cost from the landscape (see the module doc) and whether it damaged."""
    if theta < land.theta[0]:  # below 0.2 the body collapses onto the floor
        return float(np.interp(theta, [0.0, 0.15, land.theta[0]], [300.0, 290.0, land.mean[0]])
                     + land.std[0] * rng.standard_normal()), False
    m, s, p = (float(np.interp(theta, land.theta, a)) for a in (land.mean, land.std, land.damage))
    base = math.sqrt(max(s * s - DAMAGE_COST**2 * p * (1 - p), 16.0))
    normal = base * rng.standard_normal()
    damaged = bool(rng.random() < p)
    return m - DAMAGE_COST * p + normal + DAMAGE_COST * float(damaged), damaged


def surrogate_cost(theta: float, land: Landscape, rng: np.random.Generator) -> float:
    return surrogate_episode(theta, land, rng)[0]


#: Reality gaps of the surrogate: the robot is the landscape with its damage rate moved by
#: ``shift`` in theta (cables that break at a lower, < 0, or higher, > 0, stiffness) and the
#: undamaged part of the cost scaled by ``scale`` (another body, other motors); the simulator
#: is the landscape itself. ``wrong-optimum``: the robot's kappa 2 optimum 0.25 above the
#: simulated one.
GAPS: dict[str, tuple[float, float]] = {"small": (-0.02, 1.02), "medium": (-0.05, 1.06), "wrong-optimum": (0.25, 1.0)}
#: How a gap run uses the simulator: not at all, its optimum as the start (with the daemon's
#: consistency check after the warm-up), or the start and the critic's prior mean (``--prior-use
#: critic``: while the prior is kept, model steps, ``ersac.PRIOR_GREEDY``); (start, critic prior,
#: ERSAC keyword arguments). The last three: how else the learner could move while the critic
#: prior is kept (``prior_greedy``: None the preset's gradient steps and interleaved search, the
#: rule of the previous version; else (around, z, radius) of a ``GreedyRule``).
GAP_METHODS: dict[str, tuple[bool, bool, dict]] = {
    "no prior": (False, False, {}),
    "start only": (True, False, {}),
    "start + critic prior": (True, True, {}),
    "critic prior + preset steps": (True, True, {"prior_greedy": None}),
    "critic prior + model step z2": (True, True, {"prior_greedy": ("before", 2.0, 2.0)}),
    "critic prior + model step r1": (True, True, {"prior_greedy": ("before", 1.0, 1.0)}),
}
#: The rows of the table unless ``--methods`` says otherwise.
GAP_DEFAULT = ("no prior", "start only", "start + critic prior", "critic prior + preset steps")
#: "F(theta, 2) within 5 % of the robot's optimum".
BAND = 0.05


def robot_landscape(land: Landscape, shift: float, scale: float) -> Landscape:
    """The landscape of a robot whose damage rate is ``land``'s moved by ``shift`` in theta and
    whose undamaged cost is ``scale`` times ``land``'s (mean and spread), on ``land``'s grid."""
    p = land.damage
    base_mean = land.mean - DAMAGE_COST * p
    base_var = np.maximum(land.std**2 - DAMAGE_COST**2 * p * (1 - p), 16.0)
    pr = np.interp(land.theta - shift, land.theta, p)
    return Landscape(land.theta, scale * base_mean + DAMAGE_COST * pr,
                     np.sqrt(scale**2 * base_var + DAMAGE_COST**2 * pr * (1 - pr)), pr)


def default_learner() -> dict:
    """ERSAC keyword arguments of the daemon's default bracing learner (its preset)."""
    from ersac_hil.learner.presets import TASK_LEARNER, preset

    p = preset(TASK_LEARNER["bracing"])
    return {"max_step": p.max_step, "interleave_every": p.interleave_every, "greedy": p.greedy}


def _gap_run(job: tuple[str, str, float, int, str | None]) -> dict:
    """One learning run of the default bracing learner on the robot of ``gap`` as the daemon makes
    it (start, warm-up, the prior's consistency check, final selection): the policy mean after
    every episode (the last one the final selection) and the damaged episodes."""
    from threadpoolctl import threadpool_limits

    from ersac_hil.daemon.config import task_defaults
    from ersac_hil.learner import ERSAC
    from ersac_hil.learner.prior import from_groups

    gap, method, kappa, seed, path = job
    from ersac_hil.learner.ersac import GreedyRule

    start, critic, extra = GAP_METHODS[method]
    if extra.get("prior_greedy") is not None:
        around, z, radius = extra["prior_greedy"]
        extra = {**extra, "prior_greedy": GreedyRule(z=z, radius=radius, min_move=0.0, around=around)}
    sim = Landscape.load(path)
    robot = robot_landscape(sim, *GAPS[gap])
    d = task_defaults("bracing")
    prior = from_groups([[t] for t in sim.theta], sim.mean, sim.std, kappa, "landscape", sim.damage)
    theta0 = prior.theta if start else d.theta0
    with threadpool_limits(1, user_api="blas"):
        L = ERSAC(theta0, d.sigma, d.eta, kappa, d.epsilon, [[0.0, 1.0]], lr_range=d.lr_range, seed=seed,
                  **{**default_learner(), **extra})
        if critic:
            L.set_critic_prior(prior.critic_prior())
        rng = np.random.default_rng(10_000 + seed)
        path_theta, damaged, costs, rejected = [float(L.theta[0])], [], [], None
        for i in range(d.episodes):
            x = L.ask()
            c, dmg = surrogate_episode(float(x[0]), robot, rng)
            L.tell(x, c)
            costs.append(c)
            damaged.append(dmg)
            if start and i + 1 == L.min_observations:
                ok, why = prior.consistent(costs, damaged)
                if not ok:
                    rejected = why
                    L.theta = d.theta0
                    L.set_critic_prior(None)
            path_theta.append(float(L.theta[0]))
        if kappa > 0:
            path_theta[-1] = float(L.select(kappa, pessimism=kappa).theta[0])
    return {"gap": gap, "method": method, "kappa": kappa, "seed": seed, "theta": path_theta,
            "damaged": damaged, "rejected": rejected}


def settled_after(thetas: Sequence[float], land: Landscape, kappa: float) -> int | None:
    """Episodes until F(theta, kappa) of the policy stays within ``BAND`` of the optimum's
    to the end (None: not at the end)."""
    best = land.F(land.optimum(kappa), kappa)
    inside = [land.F(t, kappa) <= (1 + BAND) * best for t in thetas]
    if not inside[-1]:
        return None
    n = len(inside)
    while n > 0 and inside[n - 1]:
        n -= 1
    return n


def gaps_bench(args: argparse.Namespace) -> None:
    import multiprocessing as mp
    seeds, kappa = parse_seeds(args.seeds), 2.0
    gaps = args.gaps.split(",")
    methods = args.methods.split(",")
    jobs = [(g, m, kappa, s, args.landscape) for s in seeds for g in gaps for m in methods]
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    done: dict[tuple, dict] = {}
    runs = Path(args.out).with_suffix(".runs.jsonl") if args.out else None
    if runs is not None and runs.exists():  # resumable: a finished run is never run again
        for line in runs.read_text().splitlines():
            r = json.loads(line)
            done[(r["gap"], r["method"], r["kappa"], r["seed"])] = r
    todo = [j for j in jobs if j[:4] not in done]
    with mp.get_context("fork").Pool(2) as pool:
        for r in pool.imap_unordered(_gap_run, todo):
            done[(r["gap"], r["method"], r["kappa"], r["seed"])] = r
            if runs is not None:
                with runs.open("a") as f:
                    f.write(json.dumps(r) + "\n")
            print(f"gaps: {r['gap']} / {r['method']} / seed {r['seed']} done ({len(done)}/{len(jobs)})", flush=True)
    res = [done[j[:4]] for j in jobs]
    sim = Landscape.load(args.landscape)
    print(f"gaps: {len(jobs)} runs of {len(seeds)} seeds (45 episodes, kappa 2, the default learner), "
          f"{(time.monotonic() - t0) / 60:.1f} min, load {load0:.1f} -> {os.getloadavg()[0]:.1f}")
    print("| gap (damage shift, cost scale) | robot optimum (simulated) | method | episodes until F within 5 % "
          "stays, median [IQR] (settled) | damage events while learning, mean | final within 0.1 | prior rejected |")
    print("|---|---|---|---|---|---|---|")
    table = []
    for g in gaps:
        robot = robot_landscape(sim, *GAPS[g])
        opt = robot.optimum(kappa)
        for m in methods:
            rows = [r for r in res if r["gap"] == g and r["method"] == m]
            n = [settled_after(r["theta"], robot, kappa) for r in rows]
            e = np.array([len(r["theta"]) if v is None else v for v in n], dtype=float)  # unsettled: > budget
            dmg = float(np.mean([sum(r["damaged"]) for r in rows]))
            within = sum(abs(r["theta"][-1] - opt) <= TOLERANCE + 1e-9 for r in rows)
            rej = sum(r["rejected"] is not None for r in rows)
            med = np.median(e)
            fmt = lambda v: ">45" if v > 45 else f"{v:.0f}"  # noqa: E731
            print(f"| {g} ({GAPS[g][0]:+.2f}, x{GAPS[g][1]:.2f}) | {opt:.2f} ({sim.optimum(kappa):.2f}) | {m} | "
                  f"{fmt(med)} [{fmt(np.percentile(e, 25))}-{fmt(np.percentile(e, 75))}] "
                  f"({sum(v is not None for v in n)}/{len(rows)}) | {dmg:.2f} | {within}/{len(rows)} | {rej}/{len(rows)} |")
            table.append({"gap": g, "method": m, "robot_optimum": opt, "episodes": e.tolist(), "damage": dmg,
                          "within": int(within), "rejected": rej})
    if args.out:
        Path(args.out).write_text(json.dumps({"seeds": seeds, "gaps": GAPS, "table": table, "runs": res}, indent=1))


def surrogate_learner(method: str, kappa: float, seed: int):  # noqa: ANN201
    """The ERSAC of ``SURROGATE[method]`` for one bracing run (the task's paper settings)."""
    from ersac_hil.daemon.config import task_defaults
    from ersac_hil.learner import ERSAC
    from ersac_hil.learner.ersac import GreedyRule

    d = task_defaults("bracing")
    kwargs = dict(SURROGATE[method][0])
    theta0 = (kwargs.pop("theta0"),) if "theta0" in kwargs else d.theta0
    sigma = (kwargs.pop("sigma"),) if "sigma" in kwargs else d.sigma
    if "greedy" in kwargs:
        kwargs["greedy"] = GreedyRule(**kwargs["greedy"])
    return ERSAC(theta0, sigma, d.eta, kappa, d.epsilon, [[0.0, 1.0]], lr_range=d.lr_range, seed=seed, **kwargs)


def _surrogate_run(job: tuple[str, float, int, str | None]) -> tuple:
    """One run: (method, kappa, seed, last iterate, final policy, selection at kappa, CPU s,
    the policy mean after every episode)."""
    from threadpoolctl import threadpool_limits

    from ersac_hil.daemon.config import task_defaults

    method, kappa, seed, path = job
    land = Landscape.load(path)
    t0 = time.process_time()
    with threadpool_limits(1, user_api="blas"):
        L = surrogate_learner(method, kappa, seed)
        rng = np.random.default_rng(10_000 + seed)
        path = []
        for _ in range(task_defaults("bracing").episodes):
            x = L.ask()
            L.tell(x, surrogate_cost(float(x[0]), land, rng))
            path.append(float(L.theta[0]))
        last = float(L.theta[0])
        sel = float(L.select(kappa, pessimism=kappa).theta[0])
    final = sel if SURROGATE[method][1] and kappa > 0 else last
    return method, kappa, seed, last, final, sel, time.process_time() - t0, path


def surrogate(args: argparse.Namespace) -> None:
    import multiprocessing as mp
    seeds, kappas = parse_seeds(args.seeds), [float(k) for k in args.kappas.split(",")]
    methods = args.methods.split(",")
    jobs = [(m, k, s, args.landscape) for m in methods for k in kappas for s in seeds]
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    with mp.get_context("fork").Pool(args.processes) as pool:
        res = list(pool.imap(_surrogate_run, jobs))
    land = Landscape.load(args.landscape)
    print(f"surrogate: {len(jobs)} runs of {len(seeds)} seeds, {time.monotonic() - t0:.0f} s wall, "
          f"{sum(r[6] for r in res):.0f} s CPU, load average {load0:.1f} -> {os.getloadavg()[0]:.1f}")
    print("| method | kappa | optimum | final policy within 0.1 | median [IQR] | damage rate of the final policies "
          "(optimum) | last iterate within 0.1 | selection at every kappa within 0.1 | mean of the last 10 "
          "policies within 0.1 |")
    print("|---|---|---|---|---|---|---|---|---|")
    within = lambda a, opt: int(np.sum(np.abs(a - opt) <= TOLERANCE + 1e-9))  # noqa: E731
    for m in methods:
        for k in kappas:
            opt = land.optimum(k)
            rows = [r for r in res if r[0] == m and r[1] == k]
            last, final, sel = (np.array([r[i] for r in rows]) for i in (3, 4, 5))
            avg = np.array([np.mean(r[7][-10:]) for r in rows])
            print(f"| {m} | {k:g} | {opt:.2f} | {within(final, opt)}/{len(final)} | "
                  f"{np.median(final):.2f} [{np.percentile(final, 25):.2f}-{np.percentile(final, 75):.2f}] | "
                  f"{np.mean([land.damage_at(t) for t in final]):.3f} ({land.damage_at(opt):.3f}) | "
                  f"{within(last, opt)}/{len(last)} | {within(sel, opt)}/{len(sel)} | {within(avg, opt)}/{len(avg)} |")
    if args.out:
        Path(args.out).write_text(json.dumps({"seeds": seeds, "runs": [
            dict(zip(("method", "kappa", "seed", "last", "final", "selection", "cpu_s", "path"), r)) for r in res]}, indent=1))


def kappa0_bench(args: argparse.Namespace) -> None:
    """Why kappa 0 ends short of the mean's argmin: (1) how well the landscape's n episodes per
    policy locate that argmin, (2) where the expected gradient step of the paper's rule takes
    the policy from the start within the budget, and how far one run's noise spreads it."""
    from ersac_hil.daemon.config import task_defaults

    land, d = Landscape.load(args.landscape), task_defaults("bracing")
    rng = np.random.default_rng(0)
    draws = land.mean + land.std / math.sqrt(args.n) * rng.standard_normal((20_000, land.theta.size))
    arg = land.theta[np.argmin(draws, axis=1)]
    opt = land.optimum(0.0)
    print(f"kappa 0: argmin of the landscape's mean {opt:.2f}; with {args.n} episodes per policy the argmin of "
          f"the true mean is (normal approximation of each policy's mean):")
    for t in np.unique(arg):
        print(f"  {t:.2f}: {np.mean(arg == t):.3f}")
    print(f"  within {TOLERANCE} of {opt:.2f}: {np.mean(np.abs(arg - opt) <= TOLERANCE + 1e-9):.3f}")
    sigma, (lo, hi) = float(d.sigma[0]), d.lr_range
    J = lambda t: float(np.interp(t, land.theta, land.mean))  # noqa: E731
    r = lambda t: float(np.interp(t, land.theta, land.std))  # noqa: E731

    def step(t: float) -> float:
        """The expected update: the slope the +-sigma perturbations see, alpha = eta / r."""
        slope = (J(t + sigma) - J(t - sigma)) / (2 * sigma)
        return min(max(t - min(max(d.eta / r(t), lo), hi) * slope * sigma**2, 0.0), 1.0)

    theta, path, spread = float(d.theta0[0]), [], 0.0
    updates = d.episodes - 10
    for _ in range(updates):
        theta = step(theta)
        spread += (min(max(d.eta / r(theta), lo), hi) * r(theta) * sigma) ** 2
        path.append(theta)
    print(f"expected path of the paper's rule (eta {d.eta}, sigma {sigma}, eta / r~ in [{lo}, {hi}], r~ the true "
          f"spread) from {float(d.theta0[0]):.2f} over the {updates} updates after the warm-up: "
          + ", ".join(f"{path[i]:.3f}" for i in range(4, updates, 5)))
    print(f"expected final theta {path[-1]:.3f} (target [{opt - TOLERANCE:.2f}, {opt + TOLERANCE:.2f}]); the noise "
          f"of one run spreads it by ~{math.sqrt(spread):.3f} (sd of the sum of the updates' noise, no restoring drift)")
    more = 0
    while theta < opt - TOLERANCE and more < 10_000:
        theta = step(theta)
        more += 1
    print(f"updates the expected path needs to reach {opt - TOLERANCE:.2f}: {updates + more}")


PEERS = ("CMA-ES", "MV-BO", "random")
CHECKPOINTS = (15, 30, 45)
#: The peers' tasks: the episode budget and the kappa of every run, the default learner's as
#: ``learning`` runs them (bracing kappa 2, 45 episodes; lifting risk-neutral, 30 episodes).
PEER_TASKS: dict[str, tuple[int, float]] = {"bracing": (45, 2.0), "lifting": (30, 0.0)}
#: ``peers --methods``: the default learner (daemon runs) and the peers.
PEER_METHODS = ("default", *PEERS)
LABELS = {"default": "ERSAC (default)", "prior": "ERSAC (default) + simulator prior"}


def lifting_tests(theta: Sequence[float], seed: int, n: int = plan.FULL.test_trials) -> list[TrialSpec]:
    """The ``n`` lifting test trials of a policy of run seed ``seed``: the scenario seeds of
    ``reproduce lifting``'s (``plan.test_trials``), the same for every method of that seed."""
    return plan.test_trials(tuple(float(v) for v in theta), seed, dataclasses.replace(plan.FULL, test_trials=n))


def success_rate(trials: TrialStore, theta: Sequence[float], seed: int, n: int = plan.FULL.test_trials) -> float:
    """Lifting success of ``theta`` over its ``n`` test trials (NaN until all are stored)."""
    got = trials.get(lifting_tests(theta, seed, n))
    return float(np.mean([success(t) for t in got.values()])) if len(got) == n else float("nan")


def _run_missing(worker, trials: TrialStore, specs: Sequence[TrialSpec], stop: threading.Event) -> None:  # noqa: ANN001
    from ersac_hil.reproduce.trials import run_trial

    for t in trials.missing(specs):
        run_trial(worker.link, trials, t, stop)


def learner_jobs(pool: Pool, spec: RunSpec, out: Path, tests: int) -> list[tuple[str, Callable]]:
    """The jobs of one daemon run (none when it is finished) followed, with ``tests`` > 0, by the
    lifting test trials of its final policy on the same worker (one job: the tests need the run)."""
    jobs = pool.learning_jobs([spec], out)
    if not tests:
        return jobs
    learn = jobs[0][1] if jobs else None

    def job(worker) -> None:  # noqa: ANN001
        if learn is not None:
            learn(worker)
        _run_missing(worker, pool.trials, lifting_tests(history(spec.db(out)).final_policy, spec.seed, tests), pool.stop)
    return [(f"learning {spec.name} + tests", job)]


def _peer_problem(task: str, budget: int, evaluate: Callable[[np.ndarray], float]):  # noqa: ANN202
    """bench/learner.py's ``Problem`` for ``task`` whose every draw is an episode through the
    stack (``evaluate``); its J and r are unused by the peers."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import learner as peers  # bench/learner.py: CMA-ES, MV-BO and random search
    from ersac_hil.daemon.config import task_defaults
    from protocol.zenoh import get_task

    spec, d = get_task(task), task_defaults(task)
    nan = lambda X: np.full(len(X), np.nan)  # noqa: E731
    return peers, peers.Problem(task, np.column_stack([spec.lower, spec.upper]), np.asarray(d.theta0), nan, nan,
                                budget, float(d.sigma[0]), d.eta, d.epsilon, 10, 10,
                                sample=lambda x, _noise, k: np.array([evaluate(x) for _ in range(k or 1)]))


def peer_path(out: Path, method: str, task: str, kappa: float, seed: int) -> Path:
    return out / "peers" / f"{method}-{task}-k{kappa:g}-s{seed}.json"


def peer_job(method: str, task: str, kappa: float, seed: int, budget: int, trials: TrialStore, out: Path,
             stop: threading.Event, tests: int = 0) -> Callable:
    """One peer run on a worker: every evaluation a trial with the scenario seed the daemon
    gives learner episode idx of run seed ``seed`` (a trial already stored, e.g. another peer's
    at the same start, is not run again); writes ``peers/<name>.json`` (the recommended policy
    after every episode); with ``tests`` > 0 then runs the lifting test trials of the policy
    recommended at the end of the budget."""
    from ersac_hil.daemon.runs import scenario_seed
    from ersac_hil.reproduce.trials import run_trial

    path = peer_path(out, method, task, kappa, seed)

    def job(worker) -> None:  # noqa: ANN001
        if not path.exists():
            idx, refused = [0], [0]

            def evaluate(x: np.ndarray) -> float:
                # rounded: the same policy reached through another peer's scaling is the same trial
                t = TrialSpec(task, tuple(round(float(v), 12) for v in x), scenario_seed(seed, idx[0]))
                got = trials.get([t]).get(t)
                if got is None:
                    run_trial(worker.link, trials, t, stop)
                    got = trials.get([t]).get(t)
                if got is not None and got.status == "refused":  # no episode: the peer draws another
                    refused[0] += 1
                    raise peers.Infeasible(got.detail)
                if got is None or not got.ok:
                    raise RuntimeError(f"trial {t.key} did not finish")
                idx[0] += 1
                return got.cost()

            peers, problem = _peer_problem(task, budget, evaluate)
            run = {"CMA-ES": peers.run_cma, "MV-BO": peers.run_mvbo, "random": peers.run_random}[method]
            traj, _ = run(problem, kappa, seed)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({"method": method, "task": task, "kappa": kappa, "seed": seed,
                                        "episodes": idx[0], "refused": refused[0], "recommended": np.asarray(traj).tolist()}))
        if tests:
            _run_missing(worker, trials, lifting_tests(json.loads(path.read_text())["recommended"][-1], seed, tests), stop)
    return job


def _checkpoints(budget: int) -> tuple[int, ...]:
    return (*(c for c in CHECKPOINTS if c < budget), budget)


def _peer_result(method: str, task: str, kappa: float, seed: int, budget: int, out: Path, trials: TrialStore,
                 land: Landscape, tests: int) -> list[float] | None:
    """One (method, seed) of ``peers``, ``None`` while it is not complete: bracing, the F(theta,
    2) regret of the recommended policy at every checkpoint; lifting, [success of the policy
    recommended after the budget over its test trials]."""
    cps = _checkpoints(budget)
    if method in LABELS:
        spec = run_spec(method, task, kappa, seed, budget)
        if not finished(spec, out):
            return None
        db = spec.db(out)
        if task == "lifting":
            rate = success_rate(trials, history(db).final_policy, seed, tests)
            return None if math.isnan(rate) else [rate]
        h = history(db)
        rec = [float(h.policy_after(n)[0]) for n in cps[:-1]] + [float(final_policy(db)[0])]
    else:
        path = peer_path(out, method, task, kappa, seed)
        if not path.exists():
            return None
        traj = json.loads(path.read_text())["recommended"]
        if task == "lifting":
            rate = success_rate(trials, traj[-1], seed, tests)
            return None if math.isnan(rate) else [rate]
        rec = [traj[n - 1][0] for n in cps]
    opt = land.F(land.optimum(kappa), kappa)
    return [land.F(t, kappa) - opt for t in rec]


def peers_bench(args: argparse.Namespace) -> None:
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    stop = threading.Event()
    task, seeds = args.task, parse_seeds(args.seeds)
    budget, kappa = PEER_TASKS[task]
    budget = args.episodes or budget
    methods = [*args.methods.split(","), *(("prior",) if args.with_prior else ())]
    tests = args.test_trials if task == "lifting" else 0
    flags = {m: prior_flags(out, args.landscape) if m == "prior" else () for m in methods}
    trials = TrialStore(out / "trials.db")
    wall, load = float("nan"), (os.getloadavg()[0], float("nan"))
    if not args.report_only:
        stack = _stack(out, stop, args.pairs)
        pool = Pool(stack, trials, stop, lambda line: print(line, flush=True))
        jobs = []
        for s in seeds:  # seed by seed: an interrupted bench leaves a prefix of the seeds of every method
            for m in methods:
                if m in LABELS:
                    jobs += learner_jobs(pool, run_spec(m, task, kappa, s, budget, flags[m]), out, tests)
                else:
                    jobs.append((f"{m} s{s}", peer_job(m, task, kappa, s, budget, trials, out, stop, tests)))
        t0 = time.monotonic()
        try:
            pool.run(jobs)
        finally:
            pool.close()
            stack.close()
        wall, load = time.monotonic() - t0, (load[0], os.getloadavg()[0])
    land = Landscape.load(args.landscape)
    rows: dict[str, list[list[float]]] = {}
    done: dict[str, list[int]] = {}
    for m in methods:
        label = LABELS.get(m, m)
        for s in seeds:
            r = _peer_result(m, task, kappa, s, budget, out, trials, land, tests)
            if r is not None:
                rows.setdefault(label, []).append(r)
                done.setdefault(label, []).append(s)
    when = ("from the stored results" if args.report_only else
            f"wall time {wall / 60:.1f} min, load average {load[0]:.1f} -> {load[1]:.1f}")
    if task == "bracing":
        cps = _checkpoints(budget)
        print(f"\nbracing, kappa {kappa:g}, seeds {args.seeds}: F(theta, {kappa:g}) regret of the recommended policy "
              f"(landscape; median [IQR] over seeds); {when}")
        print("| method | seeds | " + " | ".join(f"after {n}" for n in cps) + " |")
        print("|---" * (len(cps) + 2) + "|")
        for m, r in rows.items():
            a = np.array(r)
            print(f"| {m} | {len(r)} | " + " | ".join(
                f"{np.median(a[:, i]):.1f} [{np.percentile(a[:, i], 25):.1f}-{np.percentile(a[:, i], 75):.1f}]"
                for i in range(len(cps))) + " |")
        if rows:
            _plot(rows, cps, out / "tasks.png", args.seeds)
    else:
        print(f"\nlifting, kappa {kappa:g}, seeds {args.seeds}: success of the policy recommended after {budget} "
              f"episodes over {tests} test trials per seed (the default learner's test scenario seeds); {when}")
        print("| method | seeds | success after " + str(budget) + " (test trials) | seeds at 100 % | lowest seed |")
        print("|---|---|---|---|---|")
        for m, r in rows.items():
            a = np.array(r)[:, 0]
            print(f"| {m} | {len(a)} | {100 * a.mean():.1f} % ({int(round(a.sum() * tests))}/{a.size * tests}) | "
                  f"{int(np.sum(a == 1.0))}/{a.size} | {100 * a.min():.0f} % |")
        for m, r in rows.items():
            print(f"{m}: per seed " + ", ".join(f"{s}: {100 * v[0]:.0f}" for s, v in zip(done[m], r)))
        if rows:
            _plot_success(rows, out / "tasks-lifting.png", args.seeds, budget)
    missing = {LABELS.get(m, m): len(seeds) - len(done.get(LABELS.get(m, m), [])) for m in methods}
    if any(missing.values()):
        print("not complete: " + ", ".join(f"{m} {n} of {len(seeds)} seeds" for m, n in missing.items() if n))
    (out / f"peers-{task}.json").write_text(json.dumps(
        {"task": task, "kappa": kappa, "episodes": budget, "test_trials": tests, "seeds": done, "wall_s": wall,
         "load": load, ("regret" if task == "bracing" else "success"): rows}, indent=1))


def _plot(rows: dict[str, list[list[float]]], cps: Sequence[int], path: Path, seeds: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for i, (m, r) in enumerate(rows.items()):
        a = np.array(r)
        x = np.array(cps) + (i - 1.5) * 0.8
        ax.errorbar(x, np.median(a, axis=0), yerr=[np.median(a, axis=0) - np.percentile(a, 25, axis=0),
                                                   np.percentile(a, 75, axis=0) - np.median(a, axis=0)],
                    marker="o", capsize=3, label=m)
    ax.set_xlabel("bracing episodes")
    ax.set_ylabel("F(theta, 2) regret of the recommended policy")
    ax.set_xticks(cps)
    ax.set_title(f"bracing, kappa 2, run seeds {seeds}: median and IQR")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def _plot_success(rows: dict[str, list[list[float]]], path: Path, seeds: str, budget: int) -> None:
    """Lifting: the pooled success per method (bar) and every seed's (dots)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    jitter = np.random.default_rng(0)
    for i, (m, r) in enumerate(rows.items()):
        a = 100 * np.array(r)[:, 0]
        ax.bar(i, a.mean(), width=0.6, alpha=0.5)
        ax.plot(i + jitter.uniform(-0.2, 0.2, a.size), a, "k.", alpha=0.6)
        ax.text(i, 102, f"{a.mean():.0f} % ({a.size} seeds)", ha="center", fontsize=8)
    ax.set_xticks(range(len(rows)), list(rows), fontsize=8)
    ax.set_ylim(0, 110)
    ax.set_ylabel(f"lifting success after {budget} episodes (%)")
    ax.set_title(f"lifting, run seeds {seeds}: pooled (bar) and per seed (dots)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    lp = sub.add_parser("learning", help="ERSAC learning runs (daemon processes)")
    lp.add_argument("--task", choices=["bracing", "lifting"], default="bracing")
    lp.add_argument("--kappas", default="2,0")
    lp.add_argument("--seeds", default="1-20")
    lp.add_argument("--episodes", type=int, default=None)
    lp.add_argument("--methods", default="default")
    sp = sub.add_parser("surrogate", help="ERSAC settings in-process on a landscape-drawn cost (screening)")
    sp.add_argument("--kappas", default="2,0")
    sp.add_argument("--seeds", default="0-19")
    sp.add_argument("--methods", default=",".join(SURROGATE))
    sp.add_argument("--processes", type=int, default=2)
    sp.add_argument("--out", default=None, help="JSON of every run")
    pp = sub.add_parser("peers", help="CMA-ES, MV-BO, random search against the default learner")
    pp.add_argument("--task", choices=list(PEER_TASKS), default="bracing")
    pp.add_argument("--seeds", default="1-20")
    pp.add_argument("--methods", default=",".join(PEER_METHODS), help=f"of {', '.join(PEER_METHODS)}")
    pp.add_argument("--episodes", type=int, default=None, help="the budget (default: bracing 45, lifting 30)")
    pp.add_argument("--test-trials", type=int, default=plan.FULL.test_trials, help="lifting test trials per policy")
    pp.add_argument("--with-prior", action="store_true",
                    help="also the default learner with --prior (the bracing landscape; bracing only)")
    pp.add_argument("--report-only", action="store_true",
                    help="no episodes: the tables of what the output directory holds (complete seeds per method)")
    gp = sub.add_parser("gaps", help="the simulator prior on surrogate robots that differ from the simulator")
    gp.add_argument("--seeds", default="0-9")
    gp.add_argument("--gaps", default=",".join(GAPS))
    gp.add_argument("--methods", default=",".join(GAP_DEFAULT), help=f"of {', '.join(GAP_METHODS)}")
    gp.add_argument("--out", default=None, help="JSON of every run")
    kp = sub.add_parser("kappa0", help="why kappa 0 runs end short of the mean's argmin (computed, seconds)")
    kp.add_argument("--n", type=int, default=100, help="episodes per policy behind the landscape")
    kp.add_argument("--landscape", default=None, help="landscape.json of bench/bracing_sweep.py --out")
    for p in (lp, sp, pp, gp):
        p.add_argument("--landscape", default=None, help="landscape.json of bench/bracing_sweep.py --out")
    for p in (lp, pp):
        p.add_argument("--out", default="bench-tasks")
        p.add_argument("--pairs", type=int, default=1)
    lp.add_argument("--physics", default=None, help="the simulators' --physics FILE (docs/physics.md)")
    args = ap.parse_args(argv)
    known = {"surrogate": SURROGATE, "peers": PEER_METHODS, "gaps": GAP_METHODS}.get(args.what, METHODS)
    unknown = [m for m in getattr(args, "methods", "").split(",") if m and m not in known]
    if unknown:
        ap.error(f"unknown method {unknown[0]!r}; known: {', '.join(known)}")
    if args.what == "peers" and args.with_prior and args.task != "bracing":
        ap.error("--with-prior: bracing only (the prior is the bracing landscape)")
    if args.what == "peers" and (args.test_trials < 1 or (args.episodes is not None and args.episodes < 1)):
        ap.error("--episodes and --test-trials must be >= 1")
    bad_gap = [g for g in getattr(args, "gaps", "").split(",") if g and g not in GAPS]
    if bad_gap:
        ap.error(f"unknown gap {bad_gap[0]!r}; known: {', '.join(GAPS)}")
    {"surrogate": surrogate, "learning": learning, "peers": peers_bench, "gaps": gaps_bench,
     "kappa0": kappa0_bench}[args.what](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
