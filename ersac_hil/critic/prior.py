"""A simulator's prediction as the critic's prior mean: a residual model (docs/learner.md).

The critic models the robot's cost as the simulator's prediction plus a correction:

    J(x) = m(x) + f(x),          f ~ the VHGP of the residuals y - m(x)
    g(x) = o(x) + a + b'(x - c),  o(x) = 2 log s(x), the log-linear noise model on top

with m and s the simulated mean and std of one episode's cost (a landscape), interpolated
monotonically (PCHIP, C1) in 1-D and held at their end values outside the grid. Where the
simulator is right the residuals are noise and the critic's slope of r~ is the simulator's;
where it is wrong the VHGP and the log-linear model correct it, locally, with the robot's
episodes. Pure numerics.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import PchipInterpolator

from .errors import CriticInputError

__all__ = ["CriticPrior"]

#: Floor of the simulated std (relative to the largest), so that log s stays finite.
STD_FLOOR = 1e-3


@dataclass(frozen=True)
class CriticPrior:
    """Simulated mean and std of one episode's cost on a 1-D grid ``theta`` (increasing)."""

    theta: tuple[float, ...]
    mean: tuple[float, ...]
    std: tuple[float, ...]
    _m: PchipInterpolator = field(init=False, repr=False, compare=False)
    _o: PchipInterpolator = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t, m, s = (np.asarray(v, dtype=float) for v in (self.theta, self.mean, self.std))
        if not (t.ndim == 1 and t.size >= 2 and m.shape == t.shape and s.shape == t.shape):
            raise CriticInputError("critic prior: theta, mean and std must be 1-D of the same length >= 2")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(m)) and np.all(np.isfinite(s)) and np.all(s >= 0)):
            raise CriticInputError("critic prior: theta, mean and std must be finite (std >= 0)")
        if np.any(np.diff(t) <= 0):
            raise CriticInputError("critic prior: theta must be strictly increasing")
        floor = STD_FLOOR * max(float(s.max()), 1e-12)
        object.__setattr__(self, "_m", PchipInterpolator(t, m, extrapolate=False))
        object.__setattr__(self, "_o", PchipInterpolator(t, 2.0 * np.log(np.maximum(s, floor)), extrapolate=False))

    def _at(self, f: PchipInterpolator, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != 1:
            raise CriticInputError(f"critic prior: a 1-D landscape, queried with {X.shape[1]}-D points")
        x = np.clip(X[:, 0], self.theta[0], self.theta[-1])
        inside = (X[:, 0] >= self.theta[0]) & (X[:, 0] <= self.theta[-1])
        return f(x), (f.derivative()(x) * inside)[:, None]

    def mean_at(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(m (n,), dm/dx (n, 1)) at X (n, 1)."""
        return self._at(self._m, X)

    def log_var_at(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(o = 2 log s (n,), do/dx (n, 1)) at X (n, 1)."""
        return self._at(self._o, X)

    def to_dict(self) -> dict[str, Any]:
        return {"theta": list(self.theta), "mean": list(self.mean), "std": list(self.std)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CriticPrior:
        return cls(*(tuple(float(v) for v in d[k]) for k in ("theta", "mean", "std")))

    @classmethod
    def from_rows(cls, theta: Sequence[float], mean: Sequence[float], std: Sequence[float]) -> CriticPrior:
        """From per-policy statistics in any order (sorted by theta; duplicates refused)."""
        order = np.argsort(np.asarray(theta, dtype=float), kind="stable")
        pick = lambda a: tuple(float(np.asarray(a, dtype=float)[i]) for i in order)  # noqa: E731
        return cls(pick(theta), pick(mean), pick(std))

    def __reduce__(self):  # noqa: ANN204 - picklable without the interpolators
        return (CriticPrior, (self.theta, self.mean, self.std))
