"""Input validation and output standardisation shared by GP and VHGP."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import CriticInputError


def check_xy(X: object, y: object, min_points: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Validate training data.  X (n, d) finite, y (n,) finite, n >= min_points."""
    Xa = np.asarray(X, dtype=float)
    ya = np.asarray(y, dtype=float)
    if Xa.ndim != 2:
        raise CriticInputError(f"X must have shape (n, d), got {Xa.shape}")
    if ya.ndim != 1 or ya.shape[0] != Xa.shape[0]:
        raise CriticInputError(f"y must have shape ({Xa.shape[0]},), got {ya.shape}")
    if Xa.shape[0] < min_points:
        raise CriticInputError(f"need at least {min_points} points, got {Xa.shape[0]}")
    if Xa.shape[1] < 1:
        raise CriticInputError("X needs at least one column")
    if not (np.all(np.isfinite(Xa)) and np.all(np.isfinite(ya))):
        raise CriticInputError("X and y must be finite")
    return np.ascontiguousarray(Xa), np.ascontiguousarray(ya)


def check_xs(Xs: object, d: int) -> np.ndarray:
    """Validate test inputs: (m, d) (a single (d,) vector is promoted to (1, d))."""
    Xa = np.asarray(Xs, dtype=float)
    if Xa.ndim == 1 and Xa.shape[0] == d:
        Xa = Xa[None, :]
    if Xa.ndim != 2 or Xa.shape[1] != d:
        raise CriticInputError(f"Xs must have shape (m, {d}), got {Xa.shape}")
    if not np.all(np.isfinite(Xa)):
        raise CriticInputError("Xs must be finite")
    return np.ascontiguousarray(Xa)


@dataclass(frozen=True)
class Standardisation:
    """y_std = (y - mean) / scale.  scale is 1 when y is constant."""

    mean: float
    scale: float

    @classmethod
    def of(cls, y: np.ndarray) -> "Standardisation":
        """Raises CriticInputError if the spread of y overflows (|y| beyond ~1e150)."""
        with np.errstate(over="ignore", invalid="ignore"):
            m = float(np.mean(y))
            s = float(np.std(y))
        if not (np.isfinite(m) and np.isfinite(s)):
            raise CriticInputError(f"outputs span too large a range to fit (max |y| {float(np.max(np.abs(y))):.3g})")
        if s <= 1e-12 * max(1.0, abs(m)):
            s = 1.0
        return cls(m, s)

    def apply(self, y: np.ndarray) -> np.ndarray:
        return (y - self.mean) / self.scale


def input_spans(X: np.ndarray) -> np.ndarray:
    """Per-dimension extent of the inputs, floored so that one-point columns stay usable. (d,)"""
    span = X.max(0) - X.min(0)
    floor = 1e-6 * np.maximum(1.0, np.abs(X).max(0))
    return np.maximum(span, floor)


def read_only(a: np.ndarray) -> np.ndarray:
    """A view of ``a`` that cannot be written through."""
    v = a.view()
    v.flags.writeable = False
    return v
