"""The figures of ``ersac-hil reproduce`` (matplotlib, Agg, PNG): the paper's Figs. 1, 2, 4
and 6 as analogues, the bracing landscape and the learning runs. Hardware damage is red
everywhere, as in the paper."""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .stats import Landscape  # noqa: E402

__all__ = ["landscape", "bracing_runs", "fig1", "fig2", "panel_grid", "fig4", "learning_curves", "fig6"]

DAMAGE = "tab:red"
OK = "tab:blue"


def _save(fig, path: Path) -> None:  # noqa: ANN001
    fig.savefig(path, dpi=110)
    plt.close(fig)


def landscape(land: Landscape, path: Path) -> None:
    """Mean cost, the mean +- 2 std band, F2, both argmins and the damage rate per theta."""
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    m, s = land.mean, land.std
    ax.fill_between(land.thetas, m - 2 * s, m + 2 * s, alpha=0.25, label="mean +- 2 std")
    ax.plot(land.thetas, m, "o-", label="mean J")
    ax.plot(land.thetas, m + 2 * s, "--", label="F2 = mean + 2 std")
    for kappa, c in ((0.0, "k"), (2.0, "r")):
        ax.axvline(land.theta_min(kappa), color=c, lw=1, ls=":", label=f"argmin kappa {kappa:g}")
    ax.set_xlabel("theta (arm stiffness)")
    ax.set_ylabel("cost J")
    ax2 = ax.twinx()
    # the damage rate at each theta as a stem at that theta (bars of a bin width would reach
    # past the policy's bounds [0, 1] at the ends of the grid)
    rate = land.damage.mean(axis=1)
    ax2.vlines(land.thetas, 0.0, rate, color=DAMAGE, alpha=0.35, lw=5, label="damage rate")
    ax2.plot(land.thetas, rate, "_", color=DAMAGE, ms=10)
    ax2.set_ylim(0, 1)
    ax.set_xlim(-0.02, 1.02)
    ax2.set_ylabel("damage rate")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper left", bbox_to_anchor=(1.12, 1.0), fontsize=8, frameon=False)
    ax.set_title(f"bracing landscape, {land.J.shape[1]} episodes per theta")
    _save(fig, path)


def bracing_runs(runs: Mapping[str, Mapping[int, Any]], seeds: Sequence[int], target: float,
                 neutral: float, path: Path) -> None:
    """Policy mean per update of every run (kappa 2 red, kappa 0 grey) and the final thetas
    per seed, paired: each run's ``final_policy`` (the select learner's final offline selection
    where it made one), the theta the bracing statistics compare."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True,
                                 gridspec_kw={"width_ratios": [2, 1]})
    colours = {"2": "tab:red", "0": "tab:grey"}
    for k, by_seed in runs.items():
        for i, s in enumerate(seeds):
            h = by_seed[s]
            ax.plot(np.arange(0, h.n + 1), np.r_[h.theta0[0], h.theta_after[:, 0]], color=colours[k],
                    lw=1, alpha=0.7, label=f"kappa {k}" if i == 0 else None)
    for y, c, name in ((target, "r", "argmin mean + 2 std"), (neutral, "k", "argmin mean")):
        ax.axhline(y, color=c, ls=":", lw=1, label=f"Monte Carlo {name}")
        bx.axhline(y, color=c, ls=":", lw=1)
    ax.set_xlabel("episode")
    ax.set_ylabel("policy mean theta")
    ax.grid(alpha=0.3)
    # one legend under both panels, off the data (inside, the runs' lines pass under it)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    for s in seeds:
        a, b = runs["2"][s].final_policy[0], runs["0"][s].final_policy[0]
        bx.plot([0, 1], [b, a], "-o", color="tab:purple" if a < b else "tab:orange", ms=4)
    bx.set_xticks([0, 1], ["kappa 0", "kappa 2"])
    bx.set_ylabel("final theta")
    bx.set_title("paired by run seed")
    bx.grid(alpha=0.3)
    _save(fig, path)


def _critic_panel(ax, grid, J, r, kappa: float | None = None) -> None:  # noqa: ANN001
    ax.fill_between(grid, J - 2 * r, J + 2 * r, color="tab:green", alpha=0.2, label="J~ +- 2 r~")
    ax.plot(grid, J, "-", color="tab:green", lw=2, label="critic J~")
    if kappa:
        ax.plot(grid, J + kappa * r, "--", color="tab:purple", lw=1.2, label=f"F~ = J~ + {kappa:g} r~")


def _points(ax, x, y, damage) -> None:  # noqa: ANN001
    x, y, damage = np.asarray(x), np.asarray(y), np.asarray(damage, dtype=bool)
    ax.plot(x[~damage], y[~damage], "o", ms=4, color=OK, alpha=0.8, label="episode")
    if damage.any():
        ax.plot(x[damage], y[damage], "o", ms=5, color=DAMAGE, label="hardware damage")


def fig1(grid: np.ndarray, panels: Sequence[Mapping[str, Any]], land: Landscape, path: Path) -> None:
    """Paper Fig. 1: the critic after n episodes, the episodes so far, the nominal policy."""
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.8), sharey=True,
                             constrained_layout=True, squeeze=False)
    for ax, p in zip(axes[0], panels):
        _critic_panel(ax, grid, p["J"], p["r"], 2.0)
        _points(ax, p["theta"], p["cost"], p["damage"])
        ax.axvline(p["policy"], color="k", lw=1.5, label="nominal policy")
        ax.set_title(f"N = {p['n']}")
        ax.set_xlabel("theta")
        ax.set_xlim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("cost J")
    seen: dict[str, Any] = {}  # one legend beside the panels, off the data
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(label, handle)
    fig.legend(seen.values(), seen.keys(), loc="outside right upper", fontsize=7, frameon=False)
    fig.suptitle("bracing, kappa 2: the critic along learning (damage red)")
    _save(fig, path)


def fig2(grid: np.ndarray, fit, x, y, damage, n_learning: int, final: float, argmin: float,  # noqa: ANN001
         path: Path) -> None:
    """Paper Fig. 2: one fit on learning + random-policy episodes, the final policy."""
    fig, ax = plt.subplots(figsize=(9.5, 4.8), constrained_layout=True)
    if fit is not None:
        _critic_panel(ax, grid, fit[0], fit[1], 2.0)
    x, y, damage = np.asarray(x), np.asarray(y), np.asarray(damage, dtype=bool)
    learn = np.arange(len(x)) < n_learning
    ax.plot(x[learn & ~damage], y[learn & ~damage], "o", ms=4, color=OK, label="learning episode")
    ax.plot(x[~learn & ~damage], y[~learn & ~damage], "s", ms=4, mfc="none", color=OK, label="random policy")
    if damage.any():
        ax.plot(x[damage], y[damage], "o", ms=5, color=DAMAGE, label="hardware damage")
    ax.axvline(final, color="k", lw=2, label=f"final policy {final:.3f}")
    if math.isfinite(argmin):
        ax.axvline(argmin, color="tab:purple", lw=1, ls=":", label=f"argmin F~ {argmin:.3f}")
    ax.set_xlabel("theta (arm stiffness)")
    ax.set_ylabel("cost J")
    ax.set_title(f"bracing: cost distribution fitted on {len(x)} episodes")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3)
    _save(fig, path)


def _strip(ax, pos: float, values: Sequence[float], colour: str, marks=None) -> None:  # noqa: ANN001
    v = np.asarray(values, dtype=float)
    if not len(v):
        return
    ax.boxplot([v], positions=[pos], widths=0.6, showfliers=False)
    jitter = np.linspace(-0.15, 0.15, len(v))
    colours = [DAMAGE if m else colour for m in (marks if marks is not None else [False] * len(v))]
    ax.scatter(pos + jitter, v, s=12, c=colours, zorder=3)


def panel_grid(n: int, most_columns: int = 5) -> tuple[int, int]:
    """(rows, columns) for ``n`` panels side by side: at most ``most_columns`` a row and the
    rows as full as they can be (10 -> 2 x 5, 7 -> 2 x 4, 3 -> 1 x 3), so that a figure of many
    run seeds reads at page width instead of a strip of narrow panels."""
    rows = max(1, math.ceil(n / most_columns))
    return rows, max(1, math.ceil(n / rows))


def fig4(columns: Mapping[int, Sequence[tuple[str, Sequence[Any]]]], success: Callable[[Any], bool],
         path: Path) -> None:
    """Paper Fig. 4: test costs per stage (box + points, failures red), per run seed, with the
    success rate under each box; ``success(trial)`` says whether a test trial succeeded. The
    seeds' panels in a grid (:func:`panel_grid`) on one cost axis."""
    seeds = sorted(columns)
    rows, cols = panel_grid(len(seeds))
    fig, axes = plt.subplots(rows, cols, figsize=(2.7 * cols + 0.6, 3.1 * rows + 0.5), sharey=True,
                             constrained_layout=True, squeeze=False)
    panels = axes.ravel()
    for ax, seed in zip(panels, seeds):
        labels = []
        for i, (label, trials) in enumerate(columns[seed]):
            ok = [t for t in trials if t.ok]
            _strip(ax, i, [t.cost() for t in ok], OK, [not success(t) for t in ok])
            rate = np.mean([success(t) for t in trials]) if trials else math.nan
            labels.append(f"{label}\n{100 * rate:.0f} % ok")
        ax.set_xticks(range(len(labels)), labels, fontsize=8)
        ax.set_title(f"run seed {seed}", fontsize=10)
        ax.grid(alpha=0.3, axis="y")
    for ax in panels[len(seeds):]:  # a last row that is not full: no empty axes
        fig.delaxes(ax)
    for row in axes:
        row[0].set_ylabel("test cost J (failures red)")
    fig.suptitle("lifting, kappa 0: test trials of the initial and learned policies")
    _save(fig, path)


def learning_curves(histories: Mapping[int, Any], path: Path) -> None:
    """Cost per episode of every run (damage red) and, where the runs are equally long, their
    median per episode; the legend beside the axes."""
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    for seed, h in sorted(histories.items()):
        idx = np.arange(1, h.n + 1)
        ax.plot(idx, h.cost, "-", lw=0.8, alpha=0.55, label=f"run seed {seed}")
        if h.damage.any():
            ax.plot(idx[h.damage], h.cost[h.damage], "o", color=DAMAGE, ms=4)
    lengths = {h.n for h in histories.values()}
    if len(histories) > 1 and len(lengths) == 1 and lengths != {0}:
        n = lengths.pop()
        ax.plot(np.arange(1, n + 1), np.median([h.cost for h in histories.values()], axis=0), "-",
                color="k", lw=2.2, label="median over run seeds")
    ax.set_xlabel("episode")
    ax.set_ylabel("cost J")
    ax.set_title(f"learning runs: cost per episode ({len(histories)} run seeds)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3)
    _save(fig, path)


def fig6(panels: Mapping[str, tuple[Sequence[tuple[str, Sequence[float]]], Sequence[Mapping[str, Any]]]],
         significant: float, path: Path) -> None:
    """Paper Fig. 6: test costs under each context's weights for prior / selected / after n;
    mu + 2 sigma as a solid line per column; star: mean lower than the previous column,
    triangle: variance lower (p < ``significant``)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4.2), constrained_layout=True,
                             squeeze=False)
    for ax, (context, (costs, steps)) in zip(axes[0], panels.items()):
        top = 0.0
        for i, (label, values) in enumerate(costs):
            _strip(ax, i, values, OK)
            if len(values) > 1:
                mu2 = float(np.mean(values) + 2 * np.std(values, ddof=1))
                ax.hlines(mu2, i - 0.35, i + 0.35, color="k", lw=2)
                top = max(top, mu2)
        for i, step in enumerate(steps, start=1):
            marks = ("*" if step["mean_lower"] else "") + ("^" if step["variance_lower"] else "")
            for j, m in enumerate(marks):
                ax.plot(i + 0.2 * j - 0.1 * (len(marks) - 1), top * 1.05 if top else 1.0, m, ms=11,
                        color="k")
        ax.set_xticks(range(len(costs)), [label for label, _ in costs])
        ax.set_title(context.replace("_", "-"))
        ax.set_ylabel("re-weighted test cost")
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(f"lifting risk contexts (* mean, ^ variance lower than the previous column, p < {significant:g})")
    _save(fig, path)
