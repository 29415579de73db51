"""The statistics of the paper's experiments (pure: arrays in, numbers out; scipy.stats).

* :class:`Landscape` - a cost landscape J(theta) from a matrix of episode costs (thetas x
  seeds, common random numbers: seed j is the same scenario at every theta): mean, std,
  F_kappa = mean + kappa std, damage and fall rates, argmins, and paired-bootstrap standard
  errors (the seeds are resampled jointly across thetas). ``bench/bracing_sweep.py`` and
  ``ersac-hil reproduce bracing`` both use it.
* :func:`paired` - final parameters of paired runs (same run seed, two kappas): differences,
  how many pairs are lower, median difference, Wilcoxon signed-rank test.
* :func:`welch` - Welch's (Behrens-Fisher) test that a sample's mean is lower than another's.
* :func:`variance_drop` - the F (chi-squared ratio) test that a sample's variance is lower.

Every p-value is one-sided in the direction the paper claims (lower theta with kappa 2,
lower cost after learning / selection) unless the name says otherwise.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = ["Landscape", "Paired", "paired", "welch", "variance_drop", "describe"]


@dataclass(frozen=True)
class Landscape:
    """Per theta (m of them): the cost matrix ``J`` (m, n seeds), ``damage`` and ``fallen``
    flags (m, n), ``terms`` means (m, k) named ``term_names``, ``stiffness`` (m,) for the
    table, and the paired-bootstrap replicates of mean and std, ``boot_mean``/``boot_std``
    (B, m)."""

    thetas: np.ndarray
    stiffness: np.ndarray
    J: np.ndarray
    damage: np.ndarray
    fallen: np.ndarray
    term_names: tuple[str, ...]
    terms: np.ndarray
    boot_mean: np.ndarray
    boot_std: np.ndarray

    @classmethod
    def from_arrays(cls, thetas: Sequence[float], J: np.ndarray, damage: np.ndarray, fallen: np.ndarray,
                    term_names: Sequence[str], terms: np.ndarray, stiffness: Sequence[float] | None = None,
                    n_boot: int = 1000, seed: int = 0) -> Landscape:
        """``J``, ``damage``, ``fallen`` of shape (m, n); ``terms`` (m, n, k) per-episode terms."""
        J = np.asarray(J, dtype=float)
        m, n = J.shape
        if n < 2:
            raise ValueError(f"a landscape needs >= 2 episodes per theta, got {n}")
        idx = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
        samples = J[:, idx]                                    # (m, B, n): seeds resampled jointly
        return cls(np.asarray(thetas, dtype=float),
                   np.asarray(stiffness if stiffness is not None else np.full(m, math.nan), dtype=float),
                   J, np.asarray(damage, dtype=float), np.asarray(fallen, dtype=float),
                   tuple(term_names), np.asarray(terms, dtype=float).mean(axis=1),
                   samples.mean(axis=2).T, samples.std(axis=2, ddof=1).T)

    @property
    def mean(self) -> np.ndarray:
        return self.J.mean(axis=1)

    @property
    def std(self) -> np.ndarray:
        return self.J.std(axis=1, ddof=1)

    def objective(self, kappa: float) -> np.ndarray:
        """mean + kappa std per theta, shape (m,)."""
        return self.mean + kappa * self.std

    def argmin(self, kappa: float) -> int:
        return int(np.argmin(self.objective(kappa)))

    def theta_min(self, kappa: float) -> float:
        return float(self.thetas[self.argmin(kappa)])

    def se(self, kappa: float) -> np.ndarray:
        """Bootstrap standard error of mean + kappa std, shape (m,)."""
        return (self.boot_mean + kappa * self.boot_std).std(axis=0, ddof=1)

    def gap(self, kappa: float = 2.0) -> tuple[float, float]:
        """F_kappa at the kappa-0 optimum minus F_kappa at the kappa optimum, and the bootstrap
        standard error of that difference.

        The SE is paired: each replicate resamples the seeds jointly for every theta and
        takes the difference at the two (observed) optima. The issue's target asks whether
        the two optima differ in F2 by more than noise; both F2 estimates come from the same
        scenario seeds (common random numbers), so their errors are correlated, and the
        error of the difference is that of the paired resample, not sqrt(se_a^2 + se_b^2) of
        independent ones (which ignores the covariance: measured, 100 seeds, correlation 0.4,
        SE 10.5 against 11.5). The optima are kept fixed: re-selecting them in every replicate
        (their uncertainty included) gives a statistic bounded below by 0 - reported beside
        it in docs/reproduce.md, not used for the target."""
        i0, ik = self.argmin(0.0), self.argmin(kappa)
        f = self.boot_mean + kappa * self.boot_std
        return (float(self.objective(kappa)[i0] - self.objective(kappa)[ik]),
                float((f[:, i0] - f[:, ik]).std(ddof=1)))

    def rows(self) -> list[dict[str, float]]:
        """One dict per theta (JSON-ready)."""
        se_m, se_s, se_f = self.boot_mean.std(axis=0, ddof=1), self.boot_std.std(axis=0, ddof=1), self.se(2.0)
        return [{"theta": float(t), "stiffness": float(k), "mean": float(m), "mean_se": float(a),
                 "std": float(s), "std_se": float(b), "F2": float(m + 2 * s), "F2_se": float(c),
                 "damage": float(d), "fallen": float(f), **{n: float(v) for n, v in zip(self.term_names, tm)}}
                for t, k, m, a, s, b, c, d, f, tm in zip(
                    self.thetas, self.stiffness, self.mean, se_m, self.std, se_s, se_f,
                    self.damage.mean(axis=1), self.fallen.mean(axis=1), self.terms)]

    def summary(self) -> dict[str, float]:
        """Argmins of kappa 0, 1, 2, the F2 gap and its SE (JSON-ready)."""
        g, se = self.gap(2.0)
        return {"episodes_per_theta": int(self.J.shape[1]),
                **{f"argmin_kappa_{k:g}": self.theta_min(k) for k in (0.0, 1.0, 2.0)},
                "F2_gap": g, "F2_gap_se": se, "F2_gap_in_se": g / se if se > 0 else (math.inf if g > 0 else 0.0)}

    def markdown(self) -> str:
        # the rates of damage and falls first, then each cost term's mean (the damage term
        # is the damage indicator, so its mean repeats the rate: it is labelled as a term)
        head = ("| theta | K (N m/rad) | mean J | std J | F2 = mean + 2 std | damage rate | fallen rate | "
                + " | ".join(f"mean {t}" for t in self.term_names) + " |")
        lines = [head, "|" + "---|" * (7 + len(self.term_names))]
        for r in self.rows():
            lines.append(f"| {r['theta']:.2f} | {r['stiffness']:.1f} | {r['mean']:.1f} +- {r['mean_se']:.1f} "
                         f"| {r['std']:.1f} +- {r['std_se']:.1f} | {r['F2']:.1f} +- {r['F2_se']:.1f} "
                         f"| {r['damage']:.2f} | {r['fallen']:.2f} | "
                         + " | ".join(f"{r[t]:.2f}" for t in self.term_names) + " |")
        lines.append("")
        for kappa in (0.0, 1.0, 2.0):
            i = self.argmin(kappa)
            lines.append(f"argmin mean + {kappa:g} std: theta {self.thetas[i]:.2f} "
                         f"(F {self.objective(kappa)[i]:.1f} +- {self.se(kappa)[i]:.1f})")
        g, se = self.gap(2.0)
        lines.append(f"F2 at the kappa-0 optimum minus F2 at the kappa-2 optimum: {g:.1f} "
                     f"(bootstrap SE {se:.1f}, {self.summary()['F2_gap_in_se']:.1f} SE)")
        return "\n".join(lines)


@dataclass(frozen=True)
class Paired:
    """Paired final parameters ``a`` (e.g. kappa 2) and ``b`` (kappa 0), shape (n,).

    Attributes:
        diff: b - a per pair (positive: a is lower).
        n_lower: pairs with a < b.
        median_diff: median of ``diff``.
        wilcoxon_p: one-sided Wilcoxon signed-rank p that ``diff`` is centred above 0 (NaN
            with fewer than 2 non-zero differences).
    """

    a: np.ndarray
    b: np.ndarray
    diff: np.ndarray
    n_lower: int
    median_diff: float
    wilcoxon_p: float


def paired(a: Sequence[float], b: Sequence[float]) -> Paired:
    """Compare paired samples ``a`` and ``b`` (same length n): is ``a`` lower?"""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired samples need equal shapes (n,), got {a.shape} and {b.shape}")
    diff = b - a
    p = (float(stats.wilcoxon(diff, alternative="greater").pvalue)
         if np.count_nonzero(diff) >= 2 else math.nan)
    return Paired(a, b, diff, int(np.sum(a < b)), float(np.median(diff)) if len(diff) else math.nan, p)


def welch(before: Sequence[float], after: Sequence[float]) -> float:
    """One-sided Welch (Behrens-Fisher) p that ``after`` has the lower mean (NaN if either
    sample has fewer than 2 values or both have zero variance)."""
    x, y = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    if len(x) < 2 or len(y) < 2 or (np.var(x) == 0 and np.var(y) == 0):
        return math.nan
    return float(stats.ttest_ind(y, x, equal_var=False, alternative="less").pvalue)


def variance_drop(before: Sequence[float], after: Sequence[float]) -> float:
    """One-sided F test p that ``after`` has the lower variance: F = s_after^2 / s_before^2
    against F(n_after - 1, n_before - 1) (the chi-squared ratio of two normal samples)."""
    x, y = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    if len(x) < 2 or len(y) < 2:
        return math.nan
    vx, vy = np.var(x, ddof=1), np.var(y, ddof=1)
    if vx == 0:
        return math.nan if vy == 0 else 1.0
    return float(stats.f.cdf(vy / vx, len(y) - 1, len(x) - 1))


def describe(values: Sequence[float]) -> dict[str, float]:
    """n, mean, std (ddof 1), mean + 2 std, min, median, max (JSON-ready; NaN when empty)."""
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {"n": 0, "mean": math.nan, "std": math.nan, "mu_2sigma": math.nan,
                "min": math.nan, "median": math.nan, "max": math.nan}
    std = float(v.std(ddof=1)) if len(v) > 1 else 0.0
    return {"n": int(len(v)), "mean": float(v.mean()), "std": std, "mu_2sigma": float(v.mean() + 2 * std),
            "min": float(v.min()), "median": float(np.median(v)), "max": float(v.max())}
