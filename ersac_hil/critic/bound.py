"""The VHGP marginal variational bound and its analytic gradient (pure function).

See vhgp.py for the model and the equations; the gradient is checked against finite
differences in tests/ersac_hil/critic/test_vhgp.py.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import _linalg as la
from .kernels import se_ard, se_ard_hyper_grad

_LOG2PI = math.log(2.0 * math.pi)
BAD = 1e10  # the objective's value when a Cholesky fails


def unpack(p: np.ndarray, n: int, d: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, float, float]:
    return p[:n], p[n : n + d], p[n + d], p[n + d + 1 : n + 2 * d + 1], p[n + 2 * d + 1], p[n + 2 * d + 2]


def vhgp_bound(
    p: np.ndarray,
    X: np.ndarray,
    y: np.ndarray,
    jitter: float = 1e-8,
    grad: str = "all",
    cache: dict[str, Any] | None = None,
) -> tuple[float, np.ndarray | None]:
    """MV bound F and its gradient.

    p (n + 2d + 3,) = [log_lambda (n), log_ell_f (d), log_sf2, log_ell_g (d), log_sg2, mu0];
    X (n, d); y (n,) (any units; the fit passes standardised y).  grad: "all", "lambda"
    (only the first n entries are filled, the rest 0) or "none".  cache: optional dict the
    caller keeps per (X, y) to reuse the kernel matrices while their hyperparameters do not
    change (the lambda-only stage).  Returns (F, dF/dp or None); (-1e10, zeros) when a
    Cholesky fails.
    """
    n, d = X.shape
    loglam, lf, lsf, lg, lsg, mu0 = unpack(p, n, d)
    Kf = _cached_kernel(cache, "f", X, p[n : n + d + 1])
    Kg = _cached_kernel(cache, "g", X, p[n + d + 1 : n + 2 * d + 2])
    lam = np.exp(loglam)
    s = np.sqrt(lam)
    sKg = s[:, None] * Kg
    B = sKg * s[None, :]
    B[np.diag_indices(n)] += 1.0
    LB = la.cholesky(B)
    if LB is None:
        return -BAD, (np.zeros_like(p) if grad != "none" else None)
    LBi = la.tri_inverse(LB)
    V = LBi @ sKg
    Sigma = Kg - V.T @ V
    beta = lam - 0.5
    Kbeta = Kg @ beta
    dS = np.diagonal(Sigma)
    with np.errstate(over="ignore"):
        R = np.exp(Kbeta + mu0 - 0.5 * dS)
    if not np.all(np.isfinite(R)):
        return -BAD, (np.zeros_like(p) if grad != "none" else None)
    K = Kf.copy()
    K[np.diag_indices(n)] += R + jitter
    LK = la.cholesky(K)
    if LK is None:
        return -BAD, (np.zeros_like(p) if grad != "none" else None)
    LKi = la.tri_inverse(LK)
    w = LKi @ y
    F = (
        -0.5 * float(w @ w)
        - 0.5 * la.logdet(LK)
        - 0.5 * n * _LOG2PI
        - 0.25 * float(dS.sum())
        - 0.5 * (float(np.einsum("ij,ij->", LBi, LBi)) + float(beta @ Kbeta) - n + la.logdet(LB))
    )
    if grad == "none":
        return F, None
    Kinv = LKi.T @ LKi
    alpha = LKi.T @ w
    b = 0.5 * (alpha * alpha - np.diagonal(Kinv)) * R
    g = np.zeros_like(p)
    g[:n] = lam * ((Kg + 0.5 * Sigma * Sigma) @ (b + 0.5 - lam))
    if grad == "lambda":
        return F, g
    W = np.outer(alpha, alpha)
    W -= Kinv
    W *= 0.5
    g[n : n + d + 1] = se_ard_hyper_grad(X, Kf, W, lf)
    c = -0.5 * b - 0.25
    SC = Sigma * c[None, :]
    LSC = lam[:, None] * SC
    Gg = lam[:, None] * (SC @ Sigma) * lam[None, :]
    Gg -= LSC
    Gg -= LSC.T
    Gg[np.diag_indices(n)] += c
    M = (LBi.T @ LBi) * s[None, :]
    Gg -= 0.5 * (s[:, None] * M - M.T @ M)
    Gg += np.outer(b - 0.5 * beta, beta)
    g[n + d + 1 : n + 2 * d + 2] = se_ard_hyper_grad(X, Kg, Gg, lg)
    g[-1] = float(b.sum())
    return F, g


def _cached_kernel(cache: dict[str, Any] | None, name: str, X: np.ndarray, hyp: np.ndarray) -> np.ndarray:
    d = X.shape[1]
    if cache is None:
        return se_ard(X, X, hyp[:d], hyp[d])
    key = hyp.tobytes()
    hit = cache.get(name)
    if hit is not None and hit[0] == key:
        return hit[1]
    K = se_ard(X, X, hyp[:d], hyp[d])
    cache[name] = (key, K)
    return K
