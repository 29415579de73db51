"""Run reports from the store: PNG plots (matplotlib, Agg) and ``summary.json``.

Files written to ``out`` (see :func:`write_report`):

* ``learning_curve.png`` - cost of every ok episode (damaged ones marked), its running mean,
  the critic's J~ at the policy mean and the policy mean itself per update (kappa changes
  marked); failed attempts as ticks at the bottom.
* ``critic.png`` (1-D tasks) - the paper's Figure 2: cost observations against the executed
  theta (hardware damage in red), the critic mean J~ with the J~ +/- 2 r~ band,
  F~ = J~ + kappa r~, the final theta.
* ``telemetry.png`` - cost terms and telemetry summary figures of the first and last ok
  episodes, side by side.
* ``summary.json`` - final theta, kappa, weights, episode and attempt counts, cost
  statistics, wall time, critic at the final theta, file names.
"""
from __future__ import annotations

import json
import math
import statistics
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from protocol.zenoh import get_task  # noqa: E402

from .store import EpisodeRecord, RunRecord, Store  # noqa: E402

__all__ = ["write_report", "cost_statistics", "GRID_POINTS"]

#: Points of the critic curve in the 1-D plot.
GRID_POINTS = 101


def _stats(values: Sequence[float]) -> dict[str, float | int | None]:
    if not values:
        return {"n": 0, "mean": None, "std": None, "min": None, "median": None, "max": None}
    return {
        "n": len(values),
        "mean": statistics.fmean(values),
        "std": statistics.pstdev(values) if len(values) > 1 else 0.0,
        "min": min(values),
        "median": statistics.median(values),
        "max": max(values),
    }


def cost_statistics(episodes: Sequence[EpisodeRecord], window: int = 10) -> dict[str, Any]:
    """Cost statistics of ok episodes: all, first ``window`` and last ``window``; damage rate."""
    costs = [e.cost for e in episodes if e.cost is not None]
    damage = [float((e.cost_terms or {}).get("damage", 0.0)) for e in episodes]
    return {
        "all": _stats(costs),
        f"first_{window}": _stats(costs[:window]),
        f"last_{window}": _stats(costs[-window:]),
        "damage_rate": (sum(d > 0 for d in damage) / len(damage)) if damage and "damage" in
        (episodes[0].cost_terms or {}) else None,
        f"damage_rate_last_{window}": (sum(d > 0 for d in damage[-window:]) / len(damage[-window:]))
        if damage and "damage" in (episodes[0].cost_terms or {}) else None,
    }


def _damaged(episode: EpisodeRecord) -> bool:
    """The episode damaged the hardware (failure flag or a damage cost term)."""
    return (bool((episode.failures or {}).get("hardware_damage"))
            or float((episode.cost_terms or {}).get("damage", 0.0)) > 0)


def _running_mean(values: np.ndarray, window: int = 5) -> np.ndarray:
    out = np.empty_like(values)
    for i in range(len(values)):
        out[i] = values[max(0, i - window + 1): i + 1].mean()
    return out


def _learning_curve(path: Path, run: RunRecord, store: Store, episodes: list[EpisodeRecord]) -> None:
    spec = get_task(run.task)
    updates = store.updates(run.run_id)
    failed = [a for a in store.attempts(run.run_id) if a.status not in ("ok", "pending")]
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(9, 7), sharex=True, constrained_layout=True)
    idx = np.arange(1, len(episodes) + 1)
    # an update is drawn at its last episode (with a batch of k, one update per k episodes)
    position = {e.episode_id: i + 1 for i, e in enumerate(episodes)}
    at = np.array([position.get(u.episode_id, np.nan) for u in updates], dtype=float)
    costs = np.array([e.cost for e in episodes], dtype=float)
    if len(costs):
        damaged = np.array([_damaged(e) for e in episodes])
        ax.plot(idx[~damaged], costs[~damaged], "o", ms=4, color="tab:blue", label="cost (ok episode)")
        if damaged.any():
            ax.plot(idx[damaged], costs[damaged], "s", ms=5, color="tab:red", label="cost (hardware damage)")
        ax.plot(idx, _running_mean(costs), "-", color="k", lw=1.5, label="running mean (5)")
        ax.plot(at, [np.nan if u.J is None else u.J for u in updates], "--", color="tab:green", lw=1.2,
                label="critic J~(theta)")
    if failed:
        ax.plot([a.idx + 1 for a in failed], [np.nanmin(costs) if len(costs) else 0.0] * len(failed),
                "x", color="tab:orange", label=f"failed attempts ({len(failed)})")
    ax.set_ylabel("cost J")
    ax.set_title(f"run {run.run_id}: {run.task}, {len(episodes)} episodes")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    if updates:
        after = np.array([u.theta_after for u in updates])
        for d in range(after.shape[1]):
            bx.plot(at, after[:, d], "-", lw=1.2, label=spec.param_names[d])
        kappas = [u.kappa for u in updates]
        for i in range(1, len(kappas)):
            if kappas[i] != kappas[i - 1]:
                bx.axvline(at[i], color="grey", ls=":", lw=1)
                bx.text(at[i], bx.get_ylim()[1], f" kappa {kappas[i]:g}", fontsize=7, va="top")
    bx.set_xlabel("episode")
    bx.set_ylabel("policy mean theta")
    bx.legend(loc="best", fontsize=8, ncol=2)
    bx.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _critic_plot(path: Path, run: RunRecord, episodes: list[EpisodeRecord], engine: Any,
                 final_theta: Sequence[float]) -> dict[str, float]:
    spec = get_task(run.task)
    lo, hi = spec.lower[0], spec.upper[0]
    grid = np.linspace(lo, hi, GRID_POINTS)
    values = np.array(engine.critic([(float(t),) for t in grid]), dtype=float)
    J, r = values[:, 0], values[:, 1]
    kappa = engine.kappa
    fig, ax = plt.subplots(figsize=(8, 5), constrained_layout=True)
    x = np.array([e.theta[0] for e in episodes])
    y = np.array([e.cost for e in episodes], dtype=float)
    damaged = np.array([_damaged(e) for e in episodes], dtype=bool)
    ax.plot(x[~damaged], y[~damaged], "o", ms=4, color="tab:blue", alpha=0.7, label="cost observations")
    if damaged.any():
        ax.plot(x[damaged], y[damaged], "o", ms=5, color="tab:red", label="hardware damage")
    ax.fill_between(grid, J - 2 * r, J + 2 * r, color="tab:green", alpha=0.2, label="J~ +/- 2 r~")
    ax.plot(grid, J, "-", color="tab:green", lw=2, label="critic mean J~")
    if kappa != 0:
        ax.plot(grid, J + kappa * r, "--", color="tab:purple", lw=1.5, label=f"F~ = J~ + {kappa:g} r~")
    ax.axvline(final_theta[0], color="k", lw=2, zorder=5, label=f"final theta = {final_theta[0]:.3f}")
    pad = 0.02 * (hi - lo)
    ax.set_xlim(lo - pad, hi + pad)
    ax.set_xlabel(spec.param_names[0])
    ax.set_ylabel("cost J")
    ax.set_title(f"{run.task}: critic after {len(episodes)} episodes (kappa = {kappa:g})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    (j_final, r_final), = engine.critic([tuple(final_theta)])
    return {"J": float(j_final), "r": float(r_final), "F": float(j_final + kappa * r_final)}


def _telemetry_plot(path: Path, first: EpisodeRecord, last: EpisodeRecord) -> None:
    names = [("cost term", k) for k in (first.cost_terms or {})]
    names += [("telemetry", k) for k in sorted(set(first.telemetry or {}) | set(last.telemetry or {}))]
    cols = 4
    rows = max(1, math.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 2.4 * rows), constrained_layout=True,
                             squeeze=False)
    for ax, (group, name) in zip(axes.flat, names):
        source = "cost_terms" if group == "cost term" else "telemetry"
        vals = [float((getattr(e, source) or {}).get(name, math.nan)) for e in (first, last)]
        ax.bar([f"#{first.idx + 1}", f"#{last.idx + 1}"], vals, color=["tab:grey", "tab:blue"])
        ax.set_title(f"{name}", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3, axis="y")
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.suptitle(f"first (#{first.idx + 1}, theta {_vec(first.theta)}) vs last "
                 f"(#{last.idx + 1}, theta {_vec(last.theta)}) episode", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _vec(values: Sequence[float]) -> str:
    return ", ".join(f"{v:.3f}" for v in values)


def write_report(db: str | Path, run_id: str, out: str | Path) -> dict[str, Any]:
    """Write the plots and ``summary.json`` of ``run_id`` into ``out``; return the summary.

    Raises:
        StoreError / RunNotFound: no such store or run.
    """
    from .runs import rebuild_engine  # the learner is rebuilt exactly as the daemon would

    out = Path(out)
    with Store(db, readonly=True) as store:
        run = store.run(run_id)
        out.mkdir(parents=True, exist_ok=True)  # only for a run there is
        spec = get_task(run.task)
        episodes = store.ok_episodes(run_id)
        attempts = store.attempts(run_id)
        updates = store.updates(run_id)
        files = []
        _learning_curve(out / "learning_curve.png", run, store, episodes)
        files.append("learning_curve.png")
        engine = rebuild_engine(store, run) if episodes else None
        final_theta = tuple(engine.theta) if engine else tuple(run.settings["theta0"])
        critic_at_final = None
        if engine is not None and spec.dim == 1:
            critic_at_final = _critic_plot(out / "critic.png", run, episodes, engine, final_theta)
            files.append("critic.png")
        elif engine is not None:
            (j, r), = engine.critic([final_theta])
            critic_at_final = {"J": float(j), "r": float(r), "F": float(j + engine.kappa * r)}
        if episodes:
            _telemetry_plot(out / "telemetry.png", episodes[0], episodes[-1])
            files.append("telemetry.png")
        finished = [a.finished_s for a in attempts if a.finished_s is not None]
        summary = {
            "run_id": run.run_id,
            "robot": run.robot,
            "task": run.task,
            "status": run.status,
            "seed": run.seed,
            "episodes": len(episodes),
            "episode_budget": run.settings.get("episodes"),
            "attempts": len(attempts),
            "attempts_by_status": dict(Counter(a.status for a in attempts)),
            "theta0": list(run.settings["theta0"]),
            "final_theta": list(final_theta),
            "param_names": list(spec.param_names),
            "kappa_initial": run.settings["kappa"],
            "kappa": engine.kappa if engine else run.settings["kappa"],
            "weights": dict(engine.weights) if engine else run.settings["weights"],
            "cost": cost_statistics(episodes),
            "critic_at_final_theta": critic_at_final,
            "wall_time_s": (max(finished) - min(a.requested_s for a in attempts)) if finished else 0.0,
            "agent_wall_s": math.fsum(e.wall_s or 0.0 for e in episodes),
            "learner_updates": len(updates),
            "settings": run.settings,
            "files": files + ["summary.json"],
        }
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
