"""Risk contexts (paper 5.2, Fig. 6): re-weighting the cost of a learned lifting run,
offline policy selection with no new episode, then a few risk-averse episodes.

Per context (``plan.CONTEXTS``), through the daemon's control plane on a copy of the first
lifting run's store (``runs/context-<name>.db``):

1. a lingering daemon on the finished run; ``learner/weights`` put with the context's weights
   (every stored episode re-costed), ``learner/select?kappa=2;adopt=true`` (SLSQP argmin of
   F~(theta, 2) on the local critic, no episode), ``learner/kappa`` put 2; the daemon stops;
2. the daemon resumes the run with ``context_episodes`` more episodes (kappa 2, new weights);
3. test trials of the prior policy (after the lifting run), the selected policy and the
   policy after the extra episodes, costed under the context's weights.

Per column: mean, std and mu + 2 sigma; between consecutive columns the one-sided Welch p
(mean lower, a star in the figure when < 0.01) and the one-sided F p (variance lower, a
triangle when < 0.01).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from ersac_hil.daemon.clients import ClientError, LearnerClient
from protocol.zenoh import KeySpace, SelectQuery, get_task

from . import figures, lifting, plan
from .plan import Sizes
from .runner import JobFailed, Pool, RunSpec, Worker, copy_store, finished
from .stats import describe, variance_drop, welch
from .trials import TrialStore
from .views import history

__all__ = ["known_trials", "execute", "analyse", "weights_of", "SIGNIFICANT"]

SIGNIFICANT = 0.01
RISK_KAPPA = 2.0


def weights_of(context: str) -> dict[str, float]:
    """The complete lifting weights of ``context``."""
    return {**get_task("lifting").default_weights, **plan.CONTEXTS[context]}


def _selected(db: Path) -> tuple[tuple[float, ...], int] | None:
    """The adopted selection of a context store and the updates done when it was adopted."""
    theta = [(v, n) for kind, v, n in history(db).changes if kind == "theta"]
    return (tuple(theta[-1][0]), theta[-1][1]) if theta else None


def _control(pool: Pool, worker: Worker, spec: RunSpec, db: Path, context: str) -> None:
    """Step 1: weights, offline selection (adopted), kappa 2, through a lingering daemon."""
    if _selected(db) is not None and any(k == "kappa" for k, _, _ in history(db).changes):
        return
    run_id = history(db).run.run_id
    keys = KeySpace(worker.pair.robot, worker.pair.prefix)

    def steer() -> None:
        with LearnerClient(keys, pool.stack.zenoh_options(), timeout_s=60.0) as client:
            deadline = time.monotonic() + 60.0
            while True:
                try:
                    client.state(timeout_s=2.0)
                    break
                except ClientError:
                    if time.monotonic() > deadline or pool.stop.is_set():
                        raise
            client.set_weights(plan.CONTEXTS[context])
            reply = client.select(SelectQuery(RISK_KAPPA, None, True))
            pool.say(f"context {context}: selected theta {[round(t, 3) for t in reply.theta]} "
                     f"(J~ {reply.J:.4f}, r~ {reply.r:.4f}, F~ {reply.F:.4f}) with no new episode")
            client.set_kappa(RISK_KAPPA)

    pool.daemon(worker, spec, db, ("--resume", run_id, "--linger"), ready=steer)
    if _selected(db) is None:
        raise JobFailed(f"context {context}: the selection was not adopted")


def execute(pool: Pool, sizes: Sizes, out: Path) -> None:
    source = plan.lifting_runs(sizes)[0]
    lifting.execute_runs(pool, sizes, out, [source])
    jobs = []
    for context, spec in plan.context_runs(sizes):
        db = spec.db(out)
        if not db.exists():
            copy_store(source.db(out), db)
        more = ("--episodes", str(sizes.lifting_episodes + sizes.context_episodes))
        if finished(spec, out, more):
            continue

        def job(worker: Worker, context=context, spec=spec, db=db, more=more) -> None:  # noqa: ANN001
            _control(pool, worker, spec, db, context)
            pool.learn(worker, spec, out, more)
        jobs.append((f"context {context}", job))
    pool.run(jobs)
    pool.run(pool.trial_jobs([s for cols in _columns(sizes, out).values() for _, ss in cols for s in ss],
                             "context test"))


def _columns(sizes: Sizes, out: Path, done_only: bool = False) -> dict[str, list[tuple[str, list]]]:
    """Per context: (column label, test trial specs) of prior / selected / after the extra
    episodes (the runs must be done; ``done_only``: only the columns whose policy is final)."""
    source = plan.lifting_runs(sizes)[0]
    if done_only and not finished(source, out):
        return {}
    prior = tuple(history(source.db(out)).policy_after(sizes.lifting_episodes))
    more = ("--episodes", str(sizes.lifting_episodes + sizes.context_episodes))
    cols = {}
    for context, spec in plan.context_runs(sizes):
        selected = _selected(spec.db(out)) if spec.db(out).exists() else None
        thetas = [("prior", prior), ("selected", selected[0] if selected else prior)]
        if not done_only or finished(spec, out, more):
            h = history(spec.db(out))
            thetas.append((f"after {sizes.context_episodes}", tuple(h.policy_after(h.n))))
        elif selected is None:
            thetas = thetas[:1]
        cols[context] = [(label, plan.test_trials(theta, source.seed, sizes)) for label, theta in thetas]
    return cols


def known_trials(sizes: Sizes, out: Path) -> list:
    """The test trials whose policies are known so far."""
    return [s for cols in _columns(sizes, out, done_only=True).values() for _, ss in cols for s in ss]


def analyse(sizes: Sizes, out: Path, trials: TrialStore, say=print) -> dict[str, Any]:  # noqa: ANN001
    result: dict[str, Any] = {}
    panels = {}
    source_n = history(plan.lifting_runs(sizes)[0].db(out)).n
    for context, cols in _columns(sizes, out).items():
        w = weights_of(context)
        costs = []
        for label, specs in cols:
            got = trials.get(specs)
            costs.append((label, [got[s].cost(w) for s in specs if s in got and got[s].ok]))
        steps = []
        for (a, x), (b, y) in zip(costs, costs[1:]):
            pm, pv = welch(x, y), variance_drop(x, y)
            steps.append({"from": a, "to": b, "welch_p": pm, "variance_p": pv,
                          "mean_lower": pm < SIGNIFICANT, "variance_lower": pv < SIGNIFICANT})
        selected = _selected(dict(plan.context_runs(sizes))[context].db(out))
        result[context] = {
            "weights": w,
            "columns": {label: describe(c) for label, c in costs},
            "steps": steps,
            "selected_theta": list(selected[0]) if selected else None,
            "episodes_before_selection": selected[1] if selected else None,
            "source_episodes": source_n,
            "no_new_episode": bool(selected and selected[1] == source_n),
        }
        panels[context] = (costs, steps)
        say(f"context {context}: " + ", ".join(
            f"{s['from']} -> {s['to']}: mean p {s['welch_p']:.3g}, variance p {s['variance_p']:.3g}" for s in steps))
    figures.fig6(panels, SIGNIFICANT, out / "fig6_contexts.png")
    return result
