"""A simulator prior for a learning run (``ersac-hil daemon --prior PATH``), pure numerics.

What the simulator predicts for the run's task and kappa: its optimum ``theta`` (the argmin
of mean + kappa std over the simulated policies, or the offline selection of a simulated
learning run) and the cost's ``mean`` and ``std`` there. The run starts from ``theta``. After
the learner's warm-up episodes (all drawn around ``theta``), :meth:`SimPrior.consistent`
compares what the robot gave with the prediction; a robot that disagrees (a mean off by more
than ``Z`` standard errors plus ``MODEL_TOLERANCE`` of the mean, or a spread above
``SPREAD_RATIO`` times the predicted one) rejects the prior, and the run goes on from the
start it would have had without one (docs/learner.md, "Simulator prior"). A simulator that is
wrong thus costs at most the warm-up episodes, which stay in the critic as robot data.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SimPrior", "Z", "MODEL_TOLERANCE", "SPREAD_RATIO", "from_groups"]

Z = 3.0
MODEL_TOLERANCE = 0.05
SPREAD_RATIO = 2.0


@dataclass(frozen=True)
class SimPrior:
    """``theta`` (d,) the simulated optimum for ``kappa``; ``mean``, ``std`` of one
    episode's cost there (simulated); ``source`` what it was made from (one line)."""

    theta: tuple[float, ...]
    mean: float
    std: float
    kappa: float
    source: str

    def __post_init__(self) -> None:
        if not (all(math.isfinite(t) for t in self.theta) and math.isfinite(self.mean)
                and math.isfinite(self.std) and self.std >= 0):
            raise ValueError(f"prior values must be finite (std >= 0): {self}")

    def consistent(self, costs: Sequence[float]) -> tuple[bool, str]:
        """Whether robot costs observed around ``theta`` agree with the prediction, and why."""
        c = np.asarray(costs, dtype=float)
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

    def to_dict(self) -> dict[str, Any]:
        return {"theta": list(self.theta), "mean": self.mean, "std": self.std, "kappa": self.kappa,
                "source": self.source}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SimPrior:
        return cls(tuple(float(t) for t in d["theta"]), float(d["mean"]), float(d["std"]), float(d["kappa"]),
                   str(d["source"]))


def from_groups(thetas: Sequence[Sequence[float]], means: Sequence[float], stds: Sequence[float],
                kappa: float, source: str) -> SimPrior:
    """The prior of per-policy statistics (a landscape): the argmin of mean + kappa std."""
    F = np.asarray(means, dtype=float) + kappa * np.asarray(stds, dtype=float)
    if F.size == 0 or not np.any(np.isfinite(F)):
        raise ValueError("no simulated policy with a finite mean and std")
    i = int(np.nanargmin(F))
    return SimPrior(tuple(float(t) for t in thetas[i]), float(means[i]), float(stds[i]), float(kappa), source)
