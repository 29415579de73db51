"""A simulator prior for a learning run (``ersac-hil daemon --prior PATH``), pure numerics.

What the simulator predicts for the run's task and kappa: its optimum ``theta`` (the argmin
of mean + kappa std over the simulated policies, or the offline selection of a simulated
learning run) and the cost's ``mean`` and ``std`` there. The run starts from ``theta``. After
the learner's warm-up episodes (all drawn around ``theta``), :meth:`SimPrior.consistent`
compares what the robot gave with the prediction; a robot that disagrees (a mean off by more
than ``Z`` standard errors plus ``MODEL_TOLERANCE`` of the mean, or a spread above
``SPREAD_RATIO`` times the predicted one; with the simulated damage rate and the episodes'
damage flags: the damage count by its binomial tails, the mean and spread on the undamaged
episodes) rejects the prior, and the run goes on from the start it would have had without one
(docs/learner.md, "Simulator prior"). A simulator that is wrong thus costs at most the warm-up
episodes, which stay in the critic as robot data.

With ``landscape`` (the simulated mean and std of every simulated policy of a 1-D task) the
prior is also the critic's prior mean (:meth:`SimPrior.critic_prior`, the residual model of
``ersac_hil.critic.prior``) for as long as the prior is kept.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ersac_hil.critic.prior import CriticPrior

__all__ = ["SimPrior", "Z", "MODEL_TOLERANCE", "SPREAD_RATIO", "DAMAGE_ALPHA", "DAMAGE_FLOOR", "from_groups"]

Z = 3.0
MODEL_TOLERANCE = 0.05
SPREAD_RATIO = 2.0
#: Each tail of the damage count's binomial test: the one-sided normal tail of ``Z``.
DAMAGE_ALPHA = 0.5 * math.erfc(Z / math.sqrt(2.0))
#: Least simulated damage rate the count is tested against: one in a hundred, the resolution
#: of a landscape of 100 scenario seeds per policy (a rate of 0 there is "below 1 %").
DAMAGE_FLOOR = 0.01


@dataclass(frozen=True)
class SimPrior:
    """``theta`` (d,) the simulated optimum for ``kappa``; ``mean``, ``std`` of one
    episode's cost there (simulated); ``source`` what it was made from (one line);
    ``landscape`` the simulated (theta, mean, std) of every policy (1-D tasks), the critic's
    prior mean, or None; ``damage`` the simulated rate of damaged episodes at ``theta``, or
    None (not known: the check then has the costs only)."""

    theta: tuple[float, ...]
    mean: float
    std: float
    kappa: float
    source: str
    landscape: tuple[tuple[float, float, float], ...] | None = None
    damage: float | None = None

    def __post_init__(self) -> None:
        if not (all(math.isfinite(t) for t in self.theta) and math.isfinite(self.mean)
                and math.isfinite(self.std) and self.std >= 0):
            raise ValueError(f"prior values must be finite (std >= 0): {self}")
        if self.damage is not None and not (math.isfinite(self.damage) and 0.0 <= self.damage <= 1.0):
            raise ValueError(f"prior damage rate must be within [0, 1]: {self.damage}")

    def consistent(self, costs: Sequence[float], damaged: Sequence[bool] | None = None) -> tuple[bool, str]:
        """Whether robot costs observed around ``theta`` agree with the prediction, and why.

        With ``damaged`` (per episode) and a simulated ``damage`` rate, damage and cost are
        judged apart: the count of damaged episodes by a binomial test against the simulated
        rate (at least ``DAMAGE_FLOOR``; each tail ``DAMAGE_ALPHA``), the mean and spread on
        the undamaged episodes. A damaged episode is a jump (bracing: ~90 on a spread of ~4),
        so a mean and spread over all costs reject a right simulator whenever one of the
        warm-up episodes breaks a cable (docs/learner.md, "Simulator prior")."""
        c = np.asarray(costs, dtype=float)
        if damaged is not None and self.damage is not None:
            hit = np.asarray(damaged, dtype=bool)
            if hit.shape != c.shape:
                raise ValueError(f"damaged has {hit.size} flags for {c.size} costs")
            k, n, p = int(hit.sum()), int(c.size), max(self.damage, DAMAGE_FLOOR)
            from scipy.stats import binom
            above, below = float(binom.sf(k - 1, n, p)), float(binom.cdf(k, n, p))
            if min(above, below) < DAMAGE_ALPHA:
                return False, (f"robot damaged {k} of {n} episodes vs a simulated rate of {self.damage:.3g} "
                               f"(P {min(above, below):.2g} < {DAMAGE_ALPHA:.2g})")
            ok, why = self._cost_check(c[~hit])
            return ok, f"{why}; {k} of {n} damaged (simulated rate {self.damage:.3g})"
        return self._cost_check(c)

    def _cost_check(self, c: np.ndarray) -> tuple[bool, str]:
        n = c.size
        if n < 2:
            return True, "too few episodes to judge"
        m, s = float(c.mean()), float(c.std(ddof=1))
        bound = Z * max(self.std, s) / math.sqrt(n) + MODEL_TOLERANCE * abs(self.mean)
        if abs(m - self.mean) > bound:
            return False, f"robot mean {m:.4g} vs simulated {self.mean:.4g} (allowed +- {bound:.3g})"
        if s > SPREAD_RATIO * max(self.std, 1e-12):
            return False, f"robot spread {s:.4g} vs simulated {self.std:.4g} (at most {SPREAD_RATIO:g}x)"
        return True, f"robot mean {m:.4g}, spread {s:.4g} vs simulated {self.mean:.4g}, {self.std:.4g}"

    def critic_prior(self) -> CriticPrior | None:
        """The critic's prior mean of the landscape (None without one)."""
        if self.landscape is None:
            return None
        t, m, s = zip(*self.landscape)
        return CriticPrior.from_rows(t, m, s)

    def to_dict(self) -> dict[str, Any]:
        extra = {} if self.landscape is None else {"landscape": [list(r) for r in self.landscape]}
        if self.damage is not None:
            extra["damage"] = self.damage
        return {"theta": list(self.theta), "mean": self.mean, "std": self.std, "kappa": self.kappa,
                "source": self.source, **extra}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SimPrior:
        land = d.get("landscape")
        return cls(tuple(float(t) for t in d["theta"]), float(d["mean"]), float(d["std"]), float(d["kappa"]),
                   str(d["source"]), None if land is None else tuple(tuple(float(v) for v in r) for r in land),
                   None if d.get("damage") is None else float(d["damage"]))


def from_groups(thetas: Sequence[Sequence[float]], means: Sequence[float], stds: Sequence[float],
                kappa: float, source: str, damages: Sequence[float] | None = None) -> SimPrior:
    """The prior of per-policy statistics (a landscape): the argmin of mean + kappa std;
    ``damages`` the simulated damage rate of every policy (None: not known)."""
    F = np.asarray(means, dtype=float) + kappa * np.asarray(stds, dtype=float)
    if F.size == 0 or not np.any(np.isfinite(F)):
        raise ValueError("no simulated policy with a finite mean and std")
    i = int(np.nanargmin(F))
    ok = np.isfinite(F)
    land = None
    if all(len(t) == 1 for t in thetas) and int(ok.sum()) >= 2:
        land = tuple(sorted((float(thetas[j][0]), float(means[j]), float(stds[j])) for j in np.flatnonzero(ok)))
    dmg = None if damages is None else float(damages[i])
    return SimPrior(tuple(float(t) for t in thetas[i]), float(means[i]), float(stds[i]), float(kappa), source, land,
                    dmg)
