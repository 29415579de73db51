"""Squared-exponential ARD kernel with the derivatives the GP/VHGP bounds need.

k(x, x') = s2 * exp(-1/2 * sum_k (x_k - x'_k)^2 / ell_k^2)

Hyperparameters are handled in log space: log_ell (d,), log_s2 (scalar).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist


def se_ard(X1: np.ndarray, X2: np.ndarray, log_ell: np.ndarray, log_s2: float) -> np.ndarray:
    """Kernel matrix.  X1 (n, d), X2 (m, d), log_ell (d,) -> (n, m)."""
    inv = np.exp(-log_ell)
    sq = cdist(X1 * inv, X2 * inv, "sqeuclidean")
    sq *= -0.5
    sq += log_s2
    return np.exp(sq, out=sq)


def se_ard_hyper_grad(X: np.ndarray, K: np.ndarray, G: np.ndarray, log_ell: np.ndarray) -> np.ndarray:
    """Gradient of sum(G * K(theta)) with respect to [log_ell (d,), log_s2].

    X (n, d) training inputs, K (n, n) = se_ard(X, X, ...), G (n, n) any matrix (only its
    symmetric part matters).  dK/dlog_ell_k = K * (x_ik - x_jk)^2 / ell_k^2 and dK/dlog_s2 = K.
    Uses sum_ij H_ij (x_i - x_j)^2 = 2 x' diag(rowsum H) x - 2 x' H x for symmetric H, so the
    cost is O(n^2 d) without an (n, n, d) tensor.  Returns shape (d + 1,).
    """
    H = G * K
    H = 0.5 * (H + H.T)
    Z = X * np.exp(-log_ell)
    rows = H.sum(1)
    g_ell = 2.0 * (rows @ (Z * Z)) - 2.0 * np.einsum("ik,ik->k", Z, H @ Z)
    return np.concatenate([g_ell, [H.sum()]])


def se_ard_input_grad(Xs: np.ndarray, X: np.ndarray, Ks: np.ndarray, log_ell: np.ndarray) -> np.ndarray:
    """d k(xs_a, x_i) / d xs_a for every test point.

    Xs (m, d), X (n, d), Ks (m, n) = se_ard(Xs, X, ...).  Returns (m, n, d).
    """
    inv2 = np.exp(-2.0 * log_ell)
    diff = Xs[:, None, :] - X[None, :, :]
    return -Ks[:, :, None] * diff * inv2
