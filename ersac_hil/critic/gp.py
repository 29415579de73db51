"""Homoscedastic GP regression (SE-ARD kernel, constant noise), the VHGP's first stage.

Model: y = m + f(x) + e, f ~ GP(0, s2 k_ell), e ~ N(0, sn2).  m and the output scale are
fixed by standardising y; ell, s2, sn2 maximise the log marginal likelihood (L-BFGS-B,
analytic gradient).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from . import _linalg as la
from ._blas import single_threaded_blas
from ._data import Standardisation, check_xs, check_xy, input_spans
from .errors import FitError, NotFittedError
from .kernels import se_ard, se_ard_hyper_grad

_LOG2PI = math.log(2.0 * math.pi)
_BAD = 1e10


@dataclass(frozen=True)
class GPHyperparameters:
    """In the units of the data: lengthscales (d,), signal and noise variances of y."""

    lengthscales: tuple[float, ...]
    signal_variance: float
    noise_variance: float


@dataclass(frozen=True)
class GPPrediction:
    """Predictive distribution at m test points; every field has shape (m,)."""

    f_mean: np.ndarray
    f_var: np.ndarray
    noise_var: np.ndarray

    @property
    def y_var(self) -> np.ndarray:
        return self.f_var + self.noise_var

    def log_density(self, y: np.ndarray) -> np.ndarray:
        """log N(y | f_mean, y_var) per point, (m,)."""
        v = self.y_var
        return -0.5 * (_LOG2PI + np.log(v) + (np.asarray(y) - self.f_mean) ** 2 / v)


def gp_log_likelihood(p: np.ndarray, X: np.ndarray, y: np.ndarray, jitter: float) -> tuple[float, np.ndarray]:
    """Log marginal likelihood and its gradient.

    p = [log_ell (d,), log_s2, log_sn2] (standardised units); X (n, d), y (n,).
    Returns (value, gradient (d + 2,)); (-1e10, 0) when the Cholesky fails.
    """
    n, d = X.shape
    K = se_ard(X, X, p[:d], p[d])
    sn2 = math.exp(p[d + 1])
    K[np.diag_indices(n)] += sn2 + jitter
    L = la.cholesky(K)
    if L is None:
        return -_BAD, np.zeros_like(p)
    alpha = la.chol_solve(L, y)
    value = -0.5 * float(y @ alpha) - 0.5 * la.logdet(L) - 0.5 * n * _LOG2PI
    W = np.outer(alpha, alpha) - la.chol_inverse(L)
    K[np.diag_indices(n)] -= sn2 + jitter
    grad = np.empty_like(p)
    grad[: d + 1] = se_ard_hyper_grad(X, K, 0.5 * W, p[:d])
    grad[d + 1] = 0.5 * sn2 * float(np.trace(W))
    return value, grad


class GP:
    """Homoscedastic GP.  fit(X (n, d), y (n,)) -> self; predict(Xs (m, d)) -> GPPrediction.

    lengthscale_range: box for the lengthscales as multiples of the data's extent per input.
    """

    def __init__(
        self,
        hyperparameters: GPHyperparameters | None = None,
        optimize: bool = True,
        max_iter: int = 200,
        n_restarts: int = 2,
        jitter: float = 1e-8,
        lengthscale_range: tuple[float, float] = (0.01, 100.0),
    ) -> None:
        self._init_hyper = hyperparameters
        self._optimize = optimize
        self._max_iter = int(max_iter)
        self._n_restarts = max(1, int(n_restarts))
        self._jitter = float(jitter)
        self._ls_range = (float(lengthscale_range[0]), float(lengthscale_range[1]))
        self._fitted = False

    # ------------------------------------------------------------------ fit
    def _bounds(self, X: np.ndarray) -> list[tuple[float, float]]:
        span = input_spans(X)
        b = [(math.log(self._ls_range[0] * s), math.log(self._ls_range[1] * s)) for s in span]
        b.append((math.log(1e-4), math.log(1e2)))
        b.append((math.log(1e-6), math.log(10.0)))
        return b

    def _starts(self, X: np.ndarray, std: Standardisation) -> list[np.ndarray]:
        if self._init_hyper is not None:
            h = self._init_hyper
            return [
                np.concatenate(
                    [
                        np.log(np.asarray(h.lengthscales, float)),
                        [math.log(h.signal_variance / std.scale**2), math.log(h.noise_variance / std.scale**2)],
                    ]
                )
            ]
        span = input_spans(X)
        fracs = [max(f, self._ls_range[0]) for f in (0.3, 0.08, 1.0)][: self._n_restarts]
        return [np.concatenate([np.log(f * span), [0.0, math.log(0.1)]]) for f in fracs]

    def fit(self, X: object, y: object) -> "GP":
        Xa, ya = check_xy(X, y)
        std = Standardisation.of(ya)
        ys = std.apply(ya)
        with single_threaded_blas():
            best_p, best_v = None, -np.inf
            for p0 in self._starts(Xa, std):
                if self._optimize:
                    bounds = self._bounds(Xa)
                    p0 = np.clip(p0, [b[0] for b in bounds], [b[1] for b in bounds])
                    res = minimize(
                        lambda p: tuple(-v for v in gp_log_likelihood(p, Xa, ys, self._jitter)),
                        p0,
                        jac=True,
                        method="L-BFGS-B",
                        bounds=bounds,
                        options={"maxiter": self._max_iter},
                    )
                    p, v = res.x, -float(res.fun)
                else:
                    p = p0
                    v = gp_log_likelihood(p, Xa, ys, self._jitter)[0]
                if v > best_v:
                    best_p, best_v = p, v
            if best_p is None or best_v <= -_BAD:
                raise FitError("GP: no numerically valid hyperparameters found")
            self._set_state(Xa, ys, std, best_p)
        return self

    def _set_state(self, X: np.ndarray, ys: np.ndarray, std: Standardisation, p: np.ndarray) -> None:
        n, d = X.shape
        K = se_ard(X, X, p[:d], p[d])
        K[np.diag_indices(n)] += math.exp(p[d + 1]) + self._jitter
        L = la.cholesky(K)
        if L is None:  # pragma: no cover - fit() checked the same matrix
            raise FitError("GP: Cholesky failed at the fitted hyperparameters")
        self._X, self._std, self._p, self._L = X, std, p, L
        self._alpha = la.chol_solve(L, ys)
        self._fitted = True

    # ------------------------------------------------------------ predict
    def _check(self) -> None:
        if not self._fitted:
            raise NotFittedError("GP.fit() has not been called")

    @property
    def hyperparameters(self) -> GPHyperparameters:
        self._check()
        d = self._X.shape[1]
        s2 = self._std.scale**2
        return GPHyperparameters(
            tuple(float(v) for v in np.exp(self._p[:d])),
            float(math.exp(self._p[d]) * s2),
            float(math.exp(self._p[d + 1]) * s2),
        )

    def predict(self, Xs: object) -> GPPrediction:
        self._check()
        d = self._X.shape[1]
        Xt = check_xs(Xs, d)
        p, s = self._p, self._std.scale
        with single_threaded_blas():
            Ks = se_ard(Xt, self._X, p[:d], p[d])
            V = la.tri_solve(self._L, Ks.T)
        f_var = np.maximum(math.exp(p[d]) - (V * V).sum(0), 1e-300)
        m = Xt.shape[0]
        return GPPrediction(
            f_mean=self._std.mean + s * (Ks @ self._alpha),
            f_var=f_var * s * s,
            noise_var=np.full(m, math.exp(p[d + 1]) * s * s),
        )
