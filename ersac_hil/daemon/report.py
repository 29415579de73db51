"""Run reports from the store: PNG plots (matplotlib, Agg) and ``summary.json``.

Files written to ``out`` (see :func:`write_report`):

* ``learning_curve.png`` - cost of every ok episode (damaged ones marked), its running mean,
  the critic's J~ at the policy mean and the policy mean itself per update (kappa changes
  marked); failed attempts as ticks at the bottom.
* ``critic.png`` (1-D tasks) - the paper's Figure 2: cost observations against the executed
  theta (hardware damage in red), the critic mean J~ with the J~ +/- 2 r~ band and
  F~ = J~ + kappa r~ over the explored region, the final theta (``critic_plots``).
* ``risk.png`` (1-D tasks) - the risk trade-off of the run's critic: F~ for kappa 0..4 over
  the data with their argmins (offline selection), and expected cost against risk of the
  selections for kappa 0..4 (``critic_plots``).
* ``episode.png`` - the first ok episode, the first damaging one and the last against time:
  pitch, pitch rate, arm angles against their setpoints, motor currents, cable tension
  against its breaking tension, strike and ground contact marked (``episode_plot``); only
  when the agent recorded the episodes' time series (``agent --record-series DIR``, ``series``).
* ``summary.json`` - final theta, kappa, weights, episode and attempt counts, cost
  statistics, wall time, critic at the final theta, the selections for kappa 0..4, file names.
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

from protocol.zenoh import damaged, get_task  # noqa: E402

from ..episode_series import read_series  # noqa: E402
from .critic_plots import KAPPAS, TRADE_OFF_KAPPAS, critic_curve, plot_critic, plot_risk, selections  # noqa: E402
from .engine import NotEnoughData  # noqa: E402
from .episode_plot import plot_episodes  # noqa: E402
from .store import EpisodeRecord, RunRecord, Store  # noqa: E402

__all__ = ["write_report", "cost_statistics"]


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
            or bool(damaged(episode.cost_terms or {})))


def _running_mean(values: np.ndarray, window: int = 5) -> np.ndarray:
    out = np.empty_like(values)
    for i in range(len(values)):
        out[i] = values[max(0, i - window + 1): i + 1].mean()
    return out


def _learning_curve(path: Path, run: RunRecord, store: Store, episodes: list[EpisodeRecord]) -> None:
    spec = get_task(run.task)
    updates = store.updates(run.run_id)
    failed = [a for a in store.attempts(run.run_id) if a.status not in ("ok", "pending")]
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(10.5, 7), sharex=True, constrained_layout=True)
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
    if ax.get_legend_handles_labels()[0]:  # a run with no episode yet has nothing to name
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)  # off the data
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
    if bx.get_legend_handles_labels()[0]:
        bx.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bx.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _episode_series(series: Path, episodes: list[EpisodeRecord]) -> list[tuple[str, Any]]:
    """(label, series) of the first ok episode, the first that damaged the hardware and the
    last, those whose time series file is in ``series`` (unreadable files are left out)."""
    picks: list[tuple[str, EpisodeRecord]] = []
    if episodes:
        picks.append((f"first episode (#{episodes[0].idx + 1})", episodes[0]))
        damaged = [e for e in episodes if _damaged(e)]
        if damaged and damaged[0] is not episodes[0]:
            picks.append((f"first damage (#{damaged[0].idx + 1})", damaged[0]))
        if episodes[-1] not in [e for _, e in picks]:
            picks.append((f"last episode (#{episodes[-1].idx + 1})", episodes[-1]))
    out = []
    for label, e in picks:
        try:
            out.append((label, read_series(series / f"{e.episode_id}.npz")))
        except (OSError, ValueError, KeyError):
            continue
    return out


def _vec(values: Sequence[float]) -> str:
    return ", ".join(f"{v:.3f}" for v in values)


def write_report(db: str | Path, run_id: str, out: str | Path, series: str | Path | None = None
                 ) -> dict[str, Any]:
    """Write the plots and ``summary.json`` of ``run_id`` into ``out``; return the summary.
    ``series``: the directory of the agent's time series files (``agent --record-series``;
    without it, no ``episode.png``).

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
        by_kappa = None
        if engine is not None:
            try:
                (j, r), = engine.critic([final_theta])
                critic_at_final = {"J": float(j), "r": float(r), "F": float(j + engine.kappa * r)}
            except NotEnoughData:  # too few episodes for a critic: no critic, risk or selection
                engine = None
        if engine is not None and spec.dim == 1:
            damaged = np.array([_damaged(e) for e in episodes], dtype=bool)
            curve = critic_curve(run, episodes, engine)
            plot_critic(out / "critic.png", run, episodes, damaged, curve, engine.kappa, final_theta)
            files.append("critic.png")
            try:
                by_kappa = selections(engine, TRADE_OFF_KAPPAS)
            except NotEnoughData:  # too few episodes for a selection model
                by_kappa = None
            if by_kappa:
                plot_risk(out / "risk.png", run, episodes, damaged, curve,
                          [s for s in by_kappa if s["kappa"] in KAPPAS], by_kappa, engine.kappa)
                files.append("risk.png")
        shown = _episode_series(Path(series), episodes) if series is not None else []
        if shown:
            plot_episodes(out / "episode.png", shown)
            files.append("episode.png")
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
            "selection_by_kappa": by_kappa,
            "wall_time_s": (max(finished) - min(a.requested_s for a in attempts)) if finished else 0.0,
            "agent_wall_s": math.fsum(e.wall_s or 0.0 for e in episodes),
            "learner_updates": len(updates),
            "settings": run.settings,
            "files": files + ["summary.json"],
        }
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
