"""Cubic Hermite reference trajectories, as the arm firmware stores and samples them.

Knots (t_i, q_i, v_i) are given by the agent (positions and velocities per axis, times shared by
the axes of one board). On segment [t_i, t_i+1] with h = t_i+1 - t_i, s = (t - t_i) / h::

    q(t) = h00(s) q_i + h10(s) h v_i + h01(s) q_i+1 + h11(s) h v_i+1

Before the first knot the reference is (q_0, 0); after the last, (q_n-1, 0): the axis holds
the final position.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocol.can.spline import hermite_sample

from .errors import ConfigRangeError

MAX_KNOTS = 8
"""Knots per spline (the arm controller's object dictionary holds 8)."""
MAX_TIME = 60.0
"""s, latest knot time."""
MIN_SEGMENT = 0.01
"""s, shortest segment the firmware accepts (10 physics samples)."""


@dataclass(frozen=True, eq=False)
class HermiteSpline:
    """A validated multi-axis cubic Hermite spline.

    Attributes:
        times: knot times (s), shape (n,), 0 <= t_0 < t_1 < ... <= MAX_TIME, 2 <= n <= MAX_KNOTS.
        positions: knot positions (rad), shape (n, k) for k axes.
        velocities: knot velocities (rad/s), shape (n, k).
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray

    @classmethod
    def from_knots(cls, times, positions, velocities) -> "HermiteSpline":
        """Build from array-likes; 1-D positions/velocities mean one axis. Raises
        ConfigRangeError (knot count, times, shapes, non-finite values)."""
        t = np.asarray(times, dtype=float).reshape(-1)
        q = np.asarray(positions, dtype=float)
        v = np.asarray(velocities, dtype=float)
        if q.ndim == 1:
            q = q[:, None]
        if v.ndim == 1:
            v = v[:, None]
        n = t.size
        if not 2 <= n <= MAX_KNOTS:
            raise ConfigRangeError("spline.knot_count", n, 2, MAX_KNOTS)
        if q.shape[0] != n or v.shape != q.shape:
            raise ConfigRangeError("spline.shape", q.shape[0] if q.shape[0] != n else v.shape[0], n, n)
        for name, arr in (("spline.times", t), ("spline.positions", q), ("spline.velocities", v)):
            if not np.all(np.isfinite(arr)):
                raise ConfigRangeError(name, float(arr[~np.isfinite(arr)].flat[0]), -math.inf, math.inf)
        if not 0.0 <= t[0] <= MAX_TIME:
            raise ConfigRangeError("spline.times[0]", float(t[0]), 0.0, MAX_TIME)
        for i in range(1, n):
            low = t[i - 1] + MIN_SEGMENT
            if not low <= t[i] <= MAX_TIME:
                raise ConfigRangeError(f"spline.times[{i}]", float(t[i]), float(low), MAX_TIME)
        for arr in (t, q, v):
            arr.setflags(write=False)
        return cls(t, q, v)

    @property
    def n_axes(self) -> int:
        return self.positions.shape[1]

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference at times ``t`` (s since start), shape (m,) -> (q, qd), each shape (m, k)
        (the interpolation of the contract, ``protocol.can.spline``)."""
        return hermite_sample(self.times, self.positions, self.velocities, t)
