"""The VHGP marginal variational bound, its analytic gradient and a Gauss-Newton step in
lambda (pure functions).

See vhgp.py for the model and the equations; the gradient and the Newton step are checked
against finite differences and an explicit solve in tests/ersac_hil/critic/test_vhgp.py.

Cost per evaluation (n points): Cholesky factors of B and K, one triangular solve for Sigma,
and for the gradient the inverse of K and one product Sigma D Sigma: about 7 n^3/3 flops of
BLAS/LAPACK.  Two identities keep it there: B^-1 = I - Lambda^1/2 Sigma Lambda^1/2 (so
tr(B^-1) = n - tr(Lambda Sigma) and no inverse of B is formed), and the KL's derivative with
respect to Kg folds into one product (see _kg_gradient).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import blas, lapack, solve_triangular

from .kernels import se_ard, se_ard_hyper_grad

_LOG2PI = math.log(2.0 * math.pi)
BAD = 1e10  # the objective's value when a Cholesky fails


def unpack(p: np.ndarray, n: int, d: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, float, float]:
    return p[:n], p[n : n + d], p[n + d], p[n + d + 1 : n + 2 * d + 1], p[n + 2 * d + 1], p[n + 2 * d + 2]


@dataclass(frozen=True, eq=False)
class BoundState:
    """Everything the bound, its gradient and the Newton step share at one p.  Arrays (n,)
    or (n, n); V = L_B^-1 Lambda^1/2 Kg (Sigma = Kg - V'V); LK is the lower Cholesky factor
    of K = Kf + R + jitter I."""

    F: float
    lam: np.ndarray
    Kf: np.ndarray
    Kg: np.ndarray
    V: np.ndarray
    beta: np.ndarray
    R: np.ndarray
    LK: np.ndarray

    def sigma(self) -> np.ndarray:
        """Sigma = Kg - V'V (n, n): only the gradient and the Newton step need all of it."""
        return self.Kg - self.V.T @ self.V

    def k_inverse(self) -> np.ndarray:
        """K^-1 (n, n) = L_K^-T L_K^-1 (faster here than LAPACK's dpotri)."""
        Li, info = lapack.dtrtri(self.LK, lower=1)
        if info != 0:  # pragma: no cover - LK came from a successful Cholesky
            raise np.linalg.LinAlgError(f"dtrtri info={info}")
        return Li.T @ Li


def evaluate(p: np.ndarray, X: np.ndarray, y: np.ndarray, jitter: float = 1e-8, cache: dict[str, Any] | None = None) -> "BoundState | None":
    """The bound F and the matrices behind it; None where a Cholesky fails or R overflows."""
    n, d = X.shape
    loglam, _, _, _, _, mu0 = unpack(p, n, d)
    Kf = _cached_kernel(cache, "f", X, p[n : n + d + 1])
    Kg = _cached_kernel(cache, "g", X, p[n + d + 1 : n + 2 * d + 2])
    lam = np.exp(loglam)
    s = np.sqrt(lam)
    sKg = s[:, None] * Kg
    B = sKg * s[None, :]
    B.flat[:: n + 1] += 1.0
    LB, info = lapack.dpotrf(B, lower=1, clean=1, overwrite_a=1)
    if info != 0:
        return None
    V = blas.dtrsm(1.0, LB, sKg, lower=1)
    dS = Kg.diagonal() - np.einsum("ij,ij->j", V, V)
    beta = lam - 0.5
    Kbeta = Kg @ beta
    with np.errstate(over="ignore"):
        R = np.exp(Kbeta + mu0 - 0.5 * dS)
    if not np.all(np.isfinite(R)):
        return None
    K = Kf.copy()
    K.flat[:: n + 1] += R + jitter
    LK, info = lapack.dpotrf(K, lower=1, clean=1, overwrite_a=1)
    if info != 0 or not np.all(np.isfinite(LK.diagonal())):
        return None
    w = solve_triangular(LK, y, lower=True, check_finite=False)
    logdet_K = 2.0 * float(np.log(LK.diagonal()).sum())
    logdet_B = 2.0 * float(np.log(LB.diagonal()).sum())
    # KL = 1/2 [tr(B^-1) + beta' Kg beta - n + log|B|] with tr(B^-1) = n - tr(Lambda Sigma)
    kl = 0.5 * (-float(lam @ dS) + float(beta @ Kbeta) + logdet_B)
    F = -0.5 * float(w @ w) - 0.5 * logdet_K - 0.5 * n * _LOG2PI - 0.25 * float(dS.sum()) - kl
    return BoundState(F, lam, Kf, Kg, V, beta, R, LK)


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
    change.  Returns (F, dF/dp or None); (-1e10, zeros) when a Cholesky fails.
    """
    st = evaluate(p, X, y, jitter, cache)
    if st is None:
        return -BAD, (np.zeros_like(p) if grad != "none" else None)
    if grad == "none":
        return st.F, None
    return st.F, gradient(st, p, X, y, lambda_only=grad == "lambda")


def gradient(st: BoundState, p: np.ndarray, X: np.ndarray, y: np.ndarray, lambda_only: bool = False) -> np.ndarray:
    """dF/dp (n + 2d + 3,) from the state `evaluate` computed at p (only the first n entries
    with lambda_only)."""
    n, d = X.shape
    Kinv = st.k_inverse()
    alpha = Kinv @ y
    b = 0.5 * (alpha * alpha - Kinv.diagonal()) * st.R
    lam, Sigma = st.lam, st.sigma()
    g = np.zeros_like(p)
    r = b + 0.5 - lam
    g[:n] = lam * (st.Kg @ r + 0.5 * ((Sigma * Sigma) @ r))
    if lambda_only:
        return g
    W = np.outer(alpha, alpha)
    W -= Kinv
    W *= 0.5
    g[n : n + d + 1] = se_ard_hyper_grad(X, st.Kf, W, p[n : n + d])
    g[n + d + 1 : n + 2 * d + 2] = se_ard_hyper_grad(X, st.Kg, _kg_gradient(st, Sigma, b), p[n + d + 1 : n + 2 * d + 1])
    g[-1] = float(b.sum())
    return g


def _kg_gradient(st: BoundState, Sigma: np.ndarray, b: np.ndarray) -> np.ndarray:
    """dF/dKg up to its antisymmetric part (only the symmetric part enters the kernel
    gradient).  With c = -b/2 - 1/4, P = I - Sigma Lambda, B^-1 = I - Lambda^1/2 Sigma
    Lambda^1/2:

        dF/dKg = P' C P + b beta' - 1/2 beta beta' - 1/2 (Lambda^1/2 B^-1 Lambda^1/2 - Lambda^1/2 B^-2 Lambda^1/2)
               = C - 2 sym(Lambda Sigma C) + Lambda Sigma (C + Lambda / 2) Sigma Lambda - 1/2 Lambda Sigma Lambda
                 + (b - beta / 2) beta'
    """
    lam, beta = st.lam, st.beta
    c = -0.5 * b - 0.25
    LS = lam[:, None] * Sigma  # Lambda Sigma
    G = (LS * (c + 0.5 * lam)[None, :]) @ LS.T
    G -= LS * (2.0 * c + 0.5 * lam)[None, :]
    G.flat[:: lam.size + 1] += c
    G += np.outer(b - 0.5 * beta, beta)
    return G


@dataclass(frozen=True, eq=False)
class NewtonStep:
    """A Gauss-Newton step in (lambda, mu0) at fixed kernel hyperparameters.

    F: the bound where it was computed; d_lambda (n,), d_mu0: the step (in lambda, not log
    lambda; d_mu0 is 0 when mu0 is held); decrement: g' H^-1 g, twice the gain the quadratic
    model predicts."""

    F: float
    d_lambda: np.ndarray
    d_mu0: float
    decrement: float


def newton_step(st: BoundState, y: np.ndarray, with_mu0: bool = True, lambda_min: float = 0.0) -> NewtonStep | None:
    """Gauss-Newton step for lambda (and mu0) at fixed kernel hyperparameters from the
    state `evaluate` computed at p for the outputs y (n,); None if the system is singular.

    log R = Kg (lambda - 1/2) + mu0 - diag(Sigma) / 2 has Jacobian J = [H0, 1] with
    H0 = Kg + 1/2 Sigma o Sigma, and dF/dlambda = H0 (b + 1/2 - lambda), dF/dmu0 = sum(b).
    The data term's curvature in log R is replaced by its Fisher information
    D = 1/2 R (K^-1 o K^-1) R plus max(b, 0) on the diagonal (the observed curvature is
    larger where a residual exceeds its noise, b > 0: without it the first steps from a small
    noise start overshoot), the KL's by H0:  H = J' D J + [H0 0; 0 0].  Coordinates at
    lambda_min whose gradient points below it are held (active set)."""
    n = y.shape[0]
    Kinv = st.k_inverse()
    alpha = Kinv @ y
    b = 0.5 * (alpha * alpha - Kinv.diagonal()) * st.R
    Sigma = st.sigma()
    H0 = st.Kg + 0.5 * Sigma * Sigma
    D = 0.5 * st.R[:, None] * (Kinv * Kinv) * st.R[None, :]
    D.flat[:: n + 1] += np.maximum(b, 0.0)
    g_lam = H0 @ (b + 0.5 - st.lam)
    free = ~((st.lam <= lambda_min * (1.0 + 1e-9)) & (g_lam < 0.0))
    HD = H0 @ D
    H = np.empty((n + 1, n + 1))
    H[:n, :n] = HD @ H0
    H[:n, :n] += H0
    H[:n, n] = HD.sum(1)
    H[n, :n] = H[:n, n]
    H[n, n] = D.sum()
    g = np.concatenate([g_lam, [b.sum()]])
    keep = np.concatenate([free, [with_mu0]])
    Hk = H[np.ix_(keep, keep)]
    Hk.flat[:: Hk.shape[0] + 1] += 1e-10 * max(float(np.trace(Hk)) / Hk.shape[0], 1e-300)
    L, info = lapack.dpotrf(Hk, lower=1, clean=1)
    if info != 0:
        return None
    step_k = lapack.dpotrs(L, g[keep], lower=1)[0]
    step = np.zeros(n + 1)
    step[keep] = step_k
    return NewtonStep(st.F, step[:n], float(step[n]), float(g[keep] @ step_k))


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
