"""The critic's plots of a run report (1-D tasks): ``critic.png`` and ``risk.png``.

* ``critic.png`` - the paper's Figure 2: cost observations against the executed theta
  (hardware damage in red), the critic mean J~ with its J~ +/- 2 r~ band and
  F~ = J~ + kappa r~ over the explored region (within the selection's trust radius of an
  observation; the rest is shaded: there the critic is its prior, not the data), the final
  theta. The y-range is the data's with a margin; costs are never negative.
* ``risk.png`` - the risk trade-off of the run's own critic, no new episode: left, F~ for
  kappa = 0..4 over the data with each one's offline selection (``Engine.select``: argmin F~ in
  the trust region, one VHGP over all the data) marked on its curve; right, the expected cost J~ against the risk r~ of the selections
  for kappa from 0 to 4 (risk-averse selections: lower r~ for a higher J~).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402

from protocol.zenoh import get_task  # noqa: E402

from .store import EpisodeRecord, RunRecord  # noqa: E402

__all__ = ["GRID_POINTS", "KAPPAS", "CriticCurve", "critic_curve", "plot_critic", "plot_risk",
           "selections"]

#: Points of the critic curve in the 1-D plot.
GRID_POINTS = 101
#: kappa of the F~ curves in ``risk.png`` and of the selections drawn as the trade-off.
KAPPAS = (0.0, 1.0, 2.0, 3.0, 4.0)
TRADE_OFF_KAPPAS = tuple(k / 4 for k in range(17))


class CriticCurve:
    """The critic over the task's range: ``grid`` (GRID_POINTS,), ``J``, ``r`` at it, and
    ``explored`` (bool, within ``radius`` of an executed theta)."""

    def __init__(self, grid: np.ndarray, J: np.ndarray, r: np.ndarray, explored: np.ndarray,
                 radius: float) -> None:
        self.grid, self.J, self.r, self.explored, self.radius = grid, J, r, explored, radius

    def F(self, kappa: float) -> np.ndarray:
        return self.J + kappa * self.r


def critic_curve(run: RunRecord, episodes: Sequence[EpisodeRecord], engine: Any) -> CriticCurve:
    """The critic on a grid over the task's range (one VHGP per point, as the learner's)."""
    spec = get_task(run.task)
    grid = np.linspace(spec.lower[0], spec.upper[0], GRID_POINTS)
    values = np.array(engine.critic([(float(t),) for t in grid]), dtype=float)
    # the selection's trust radius (``ERSAC.select``): half the critic's neighbourhood
    radius = 0.5 * float(run.settings.get("epsilon", 0.1 * (spec.upper[0] - spec.lower[0])))
    x = np.array([e.theta[0] for e in episodes], dtype=float)
    explored = np.abs(grid[:, None] - x[None, :]).min(axis=1) <= radius
    return CriticCurve(grid, values[:, 0], values[:, 1], explored, radius)


def selections(engine: Any, kappas: Sequence[float]) -> list[dict[str, float]]:
    """``Engine.select`` for each kappa: theta, J~, r~, F~ of the offline selection."""
    out = []
    for kappa in kappas:
        theta, J, r = engine.select(float(kappa))
        out.append({"kappa": float(kappa), "theta": list(theta), "J": J, "r": r, "F": J + float(kappa) * r})
    return out


def _observations(ax: plt.Axes, episodes: Sequence[EpisodeRecord], damaged: np.ndarray,
                  colour: str = "tab:blue") -> None:
    x = np.array([e.theta[0] for e in episodes])
    y = np.array([e.cost for e in episodes], dtype=float)
    ax.plot(x[~damaged], y[~damaged], "o", ms=4, color=colour, alpha=0.7, label="cost of an episode")
    if damaged.any():
        ax.plot(x[damaged], y[damaged], "o", ms=6, color="tab:red", label="hardware damage")


def _y_range(ax: plt.Axes, values: Sequence[Sequence[float]], margin: float = 0.25) -> None:
    """The y-range of ``values`` (finite ones) with ``margin`` of their span either side, never
    below zero (costs are not negative); curves and bands that leave it are cut off."""
    flat = np.concatenate([np.asarray(v, dtype=float).ravel() for v in values])
    flat = flat[np.isfinite(flat)]
    if not flat.size:
        return
    lo, hi = float(flat.min()), float(flat.max())
    pad = margin * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.1
    ax.set_ylim(max(0.0, lo - pad), hi + pad)


def _unexplored(ax: plt.Axes, curve: CriticCurve) -> None:
    """Shade the grid spans outside the explored region."""
    step = curve.grid[1] - curve.grid[0]
    start, start_done = None, False
    for i, inside in enumerate(list(curve.explored) + [True]):
        if not inside and start is None:
            start = i
        elif inside and start is not None:
            ax.axvspan(curve.grid[start] - step / 2, curve.grid[i - 1] + step / 2, color="0.85", alpha=0.6,
                       lw=0, label=None if start_done else "unexplored (no episode near)")
            start_done = True
            start = None


def _masked(curve: CriticCurve, values: np.ndarray) -> np.ndarray:
    return np.where(curve.explored, values, np.nan)


def _frame(ax: plt.Axes, run: RunRecord) -> None:
    spec = get_task(run.task)
    lo, hi = spec.lower[0], spec.upper[0]
    pad = 0.02 * (hi - lo)
    ax.set_xlim(lo - pad, hi + pad)
    ax.set_xlabel(f"policy parameter theta ({spec.param_names[0]})")
    ax.set_ylabel("episode cost J")
    ax.grid(alpha=0.3)


def plot_critic(path: Path, run: RunRecord, episodes: Sequence[EpisodeRecord], damaged: np.ndarray,
                curve: CriticCurve, kappa: float, final_theta: Sequence[float]) -> None:
    fig, ax = plt.subplots(figsize=(9, 5), constrained_layout=True)
    _unexplored(ax, curve)
    J, r = _masked(curve, curve.J), _masked(curve, curve.r)
    ax.fill_between(curve.grid, np.maximum(J - 2 * r, 0.0), J + 2 * r, color="tab:green", alpha=0.2,
                    label="J~ +/- 2 r~")
    ax.plot(curve.grid, J, "-", color="tab:green", lw=2, label="critic mean J~")
    if kappa != 0:
        ax.plot(curve.grid, J + kappa * r, "--", color="tab:purple", lw=1.5, label=f"F~ = J~ + {kappa:g} r~")
    _observations(ax, episodes, damaged)
    ax.axvline(final_theta[0], color="k", lw=2, zorder=5, label=f"final theta = {final_theta[0]:.3f}")
    _frame(ax, run)
    _y_range(ax, [[e.cost for e in episodes], J])  # the data sets the scale, not the band
    ax.set_title(f"{run.task}: critic after {len(episodes)} episodes (kappa = {kappa:g})")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_risk(path: Path, run: RunRecord, episodes: Sequence[EpisodeRecord], damaged: np.ndarray,
              curve: CriticCurve, curves: Sequence[dict[str, float]], trade_off: Sequence[dict[str, float]],
              kappa: float) -> None:
    """``curves``: the selections at ``KAPPAS``; ``trade_off``: at ``TRADE_OFF_KAPPAS``."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 5.2), constrained_layout=True,
                                 gridspec_kw={"width_ratios": [1.35, 1]})
    cmap = ListedColormap(plt.get_cmap("viridis")(np.linspace(0.0, 0.85, 256)))  # no pale yellow
    top = max(KAPPAS) or 1.0
    _unexplored(ax, curve)
    _observations(ax, episodes, damaged, colour="0.45")
    for sel in curves:
        k = sel["kappa"]
        colour = cmap(k / top)
        F = _masked(curve, curve.F(k))
        ax.plot(curve.grid, F, "-", color=colour, lw=1.8, label=f"F~, kappa {k:g}")
        # the selection's theta, on the drawn curve (the selection fits one VHGP to all the
        # data, the curve is one VHGP per point: their minima are close, their values differ)
        ax.plot(sel["theta"][0], np.interp(sel["theta"][0], curve.grid, curve.F(k)), "v", color=colour,
                ms=11, mec="k", zorder=6)
    ax.plot([], [], "v", color="w", mec="k", ms=8, label="argmin F~ (offline selection)")
    _frame(ax, run)
    inside = curve.grid[curve.explored]
    if inside.size:  # the explored span only: the trade-off is where the data is
        ax.set_xlim(max(curve.grid[0], inside.min() - 0.02), min(curve.grid[-1], inside.max() + 0.02))
    ax.set_ylabel("F~ = J~ + kappa r~, episode cost J")
    _y_range(ax, [[e.cost for e in episodes], [np.interp(s["theta"][0], curve.grid, curve.F(s["kappa"]))
                                               for s in curves]], margin=0.3)
    ax.set_title(f"{run.task}: F~ = J~ + kappa r~ of the critic after {len(episodes)} episodes")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)

    ks = np.array([s["kappa"] for s in trade_off])
    J = np.array([s["J"] for s in trade_off])
    r = np.array([s["r"] for s in trade_off])
    theta = np.array([s["theta"][0] for s in trade_off])
    bx.plot(r, J, "-", color="0.6", lw=1, zorder=1)
    points = bx.scatter(r, J, c=ks, cmap=cmap, vmin=0, vmax=top, s=45, edgecolor="k", zorder=3)
    for i in range(len(ks)):
        if ks[i] in KAPPAS or ks[i] == kappa:
            bx.annotate(f"kappa {ks[i]:g}\ntheta {theta[i]:.3f}", (r[i], J[i]), textcoords="offset points",
                        xytext=(8, 4), fontsize=7)
    if kappa in ks:
        i = int(np.flatnonzero(ks == kappa)[0])
        bx.plot(r[i], J[i], "o", ms=14, mfc="none", mec="k", mew=1.5, label=f"this run's kappa {kappa:g}")
        bx.legend(fontsize=8, loc="upper right")
    fig.colorbar(points, ax=bx, label="kappa", ticks=list(KAPPAS))
    bx.set_xlabel("risk r~ at the selection (cost standard deviation)")
    bx.set_ylabel("expected cost J~ at the selection")
    bx.margins(0.15)
    bx.set_title("selections: more risk-averse, less risk for a higher mean")
    bx.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)
