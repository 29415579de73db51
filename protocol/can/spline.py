"""How an arm controller interpolates a downloaded spline (objects 0x2040-0x2045).

Part of the contract: the agent checks limits on the same curve the firmware will track.
Cubic Hermite segments between knots (time, position, velocity); before the first knot the
first position at rest, from the last knot on the last position at rest. Pure numpy.
"""
from __future__ import annotations

import numpy as np


def hermite_sample(times: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
                   t) -> tuple[np.ndarray, np.ndarray]:
    """Reference position and velocity at times ``t``.

    Args:
        times: knot times [s], shape ``(n,)``, strictly increasing, ``n >= 2``.
        positions: knot positions [rad], shape ``(n, k)``.
        velocities: knot velocities [rad/s], shape ``(n, k)``.
        t: sample times [s], shape ``(m,)`` (a scalar is one sample).

    Returns:
        ``(q, qd)``, each shape ``(m, k)``.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float)).reshape(-1)
    seg = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    t0, t1 = times[seg], times[seg + 1]
    h = (t1 - t0)[:, None]
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)[:, None]
    q0, q1 = positions[seg], positions[seg + 1]
    v0, v1 = velocities[seg], velocities[seg + 1]
    s2, s3 = s * s, s * s * s
    q = ((2 * s3 - 3 * s2 + 1) * q0 + (s3 - 2 * s2 + s) * h * v0
         + (-2 * s3 + 3 * s2) * q1 + (s3 - s2) * h * v1)
    qd = ((6 * s2 - 6 * s) * (q0 - q1) / h + (3 * s2 - 4 * s + 1) * v0
          + (3 * s2 - 2 * s) * v1)
    before, after = t < times[0], t >= times[-1]
    q[before], q[after] = positions[0], positions[-1]
    qd[before | after] = 0.0
    return q, qd
