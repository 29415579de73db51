"""Variational heteroscedastic GP regression (Lazaro-Gredilla & Titsias, ICML 2011).

Model: y_i = f(x_i) + e_i,  e_i ~ N(0, exp(g(x_i))),  f ~ GP(0, kf),  g ~ GP(mu0, kg),
both kernels squared-exponential ARD.  q(g) = N(mu, Sigma) with the optimal form

    Sigma = (Kg^-1 + Lambda)^-1,   mu = Kg (Lambda - 1/2) 1 + mu0,   Lambda = diag(lambda) > 0,

gives the marginal variational (MV) bound maximised over log(lambda) (n values), mu0 and
the kernel hyperparameters:

    F = log N(y | 0, Kf + R) - KL(q(g) || p(g)) - tr(Sigma) / 4,   R = diag(exp(mu_i - Sigma_ii / 2)).

All algebra goes through two Cholesky factors: of K = Kf + R + jitter I and of
B = I + Lambda^1/2 Kg Lambda^1/2 (eigenvalues >= 1, so never inverted Kg):

    KL = 1/2 [tr(B^-1) + (lambda - 1/2)' Kg (lambda - 1/2) - n + log|B|],
    Sigma = Kg - V'V with V = L_B^-1 Lambda^1/2 Kg.

Gradients (b = 1/2 diag(a a' - K^-1) * R, a = K^-1 y, beta = lambda - 1/2, c = -b/2 - 1/4):

    dF/dlambda = (Kg + 1/2 Sigma o Sigma)(b + 1/2 - lambda)
    dF/dmu0    = sum(b)
    dF/dKf     = 1/2 (a a' - K^-1)
    dF/dKg     = P' C P + b beta' - 1/2 beta beta' - 1/2 (A - M'M),
                 P = I - Sigma Lambda, C = diag(c), M = B^-1 Lambda^1/2, A = Lambda^1/2 M.

Internally y is standardised (mean 0, std 1); `VHGPParams` holds the optimiser
coordinates in those units, `VHGPHyperparameters` the same model in the units of the data.
The same jitter (1e-8 in standardised units) is used in training and prediction; a failed
Cholesky makes the objective very bad (1e10) instead of raising.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize

from . import _linalg as la
from ._blas import single_threaded_blas
from ._data import Standardisation, check_xs, check_xy, input_spans, read_only
from .bound import BAD, BoundState, evaluate, gradient, newton_step, unpack, vhgp_bound
from .errors import CriticInputError, FitError, NotFittedError
from .gp import GP
from .kernels import se_ard, se_ard_input_grad

_LOG2PI = math.log(2.0 * math.pi)
_GH_T, _GH_W = np.polynomial.hermite.hermgauss(32)


# --------------------------------------------------------------------------- value types
@dataclass(frozen=True)
class VHGPHyperparameters:
    """Kernel hyperparameters in the units of the data.

    f_lengthscales, g_lengthscales: (d,) in input units; f_variance: prior variance of f
    (units of y^2); g_variance: prior variance of the log noise variance g; g_mean: mu0, the
    prior mean of g = log noise variance (log of units of y^2).
    """

    f_lengthscales: tuple[float, ...]
    f_variance: float
    g_lengthscales: tuple[float, ...]
    g_variance: float
    g_mean: float

    def __post_init__(self) -> None:
        vals = [*self.f_lengthscales, self.f_variance, *self.g_lengthscales, self.g_variance]
        if len(self.f_lengthscales) != len(self.g_lengthscales) or not self.f_lengthscales:
            raise CriticInputError("f_lengthscales and g_lengthscales need the same length >= 1")
        if not all(math.isfinite(v) and v > 0 for v in vals) or not math.isfinite(self.g_mean):
            raise CriticInputError("hyperparameters must be finite, lengthscales/variances > 0")


@dataclass(frozen=True, eq=False)
class VHGPParams:
    """Optimiser coordinates (standardised y units), enough to rebuild a fit exactly.

    log_lambda: (n,) variational precisions; kernel: (2d + 3,) =
    [log f_lengthscales (d), log f_variance, log g_lengthscales (d), log g_variance, mu0].
    """

    log_lambda: np.ndarray
    kernel: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"log_lambda": [float(v) for v in self.log_lambda], "kernel": [float(v) for v in self.kernel]}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "VHGPParams":
        return cls(np.asarray(data["log_lambda"], dtype=float), np.asarray(data["kernel"], dtype=float))


@dataclass(frozen=True, eq=False)
class VHGPPrediction:
    """Posterior at m test points, every field (m,).

    f_mean, f_var: the latent mean function; g_mean, g_var: the latent log noise variance.
    """

    f_mean: np.ndarray
    f_var: np.ndarray
    g_mean: np.ndarray
    g_var: np.ndarray

    @property
    def noise_var(self) -> np.ndarray:
        """E_q[exp(g)] = exp(g_mean + g_var / 2): expected noise variance, (m,)."""
        return np.exp(self.g_mean + 0.5 * self.g_var)

    @property
    def noise_std(self) -> np.ndarray:
        """sqrt(E_q[exp(g)]): the critic's r~, (m,)."""
        return np.exp(0.5 * self.g_mean + 0.25 * self.g_var)

    @property
    def y_var(self) -> np.ndarray:
        """Predictive variance of y: f_var + exp(g_mean + g_var / 2), (m,)."""
        return self.f_var + self.noise_var

    def log_density(self, y: np.ndarray) -> np.ndarray:
        """Exact log predictive density log int N(y | f_mean, f_var + e^g) N(g | g_mean, g_var) dg.

        32-point Gauss-Hermite quadrature over g.  y (m,) -> (m,).
        """
        y = np.asarray(y, dtype=float)
        g = self.g_mean[:, None] + np.sqrt(2.0 * np.maximum(self.g_var, 0.0))[:, None] * _GH_T[None, :]
        v = self.f_var[:, None] + np.exp(g)
        logn = -0.5 * (_LOG2PI + np.log(v) + (y - self.f_mean)[:, None] ** 2 / v)
        a = logn + np.log(_GH_W / math.sqrt(math.pi))[None, :]
        amax = a.max(1)
        return amax + np.log(np.exp(a - amax[:, None]).sum(1))


@dataclass(frozen=True, eq=False)
class VHGPPredictionGradient:
    """d/dx of the VHGPPrediction fields at each test point, every field (m, d)."""

    f_mean: np.ndarray
    f_var: np.ndarray
    g_mean: np.ndarray
    g_var: np.ndarray


# --------------------------------------------------------------------------- the model
class VHGP:
    """Variational heteroscedastic GP.

    fit(X (n, d), y (n,)) -> self; predict(Xs (m, d)) -> VHGPPrediction; bound() -> float.

    Fitting recipe (no warm start, free hyperparameters), the authors' order with a faster
    first stage: a homoscedastic GP first (`gp_restarts` starts); the VHGP starts from its
    lengthscales (for f and g), its signal variance, lambda = 1/2 and
    mu0 = log(GP noise variance) + mu0_offset; then up to `newton_iter` Gauss-Newton steps in
    (lambda, mu0) at the GP's kernel hyperparameters (bound.newton_step, with a line search;
    the authors' stage 1 optimises lambda alone with a gradient method), then up to
    `max_iter` L-BFGS-B iterations on everything.  With `warm_start` (VHGPParams of a
    previous fit) the GP is skipped: up to `warm_newton_iter` Newton steps, then `warm_iter`
    L-BFGS-B iterations.  With `fixed_hyperparameters` only lambda is optimised (Newton
    steps; fixed-hyperparameter mode).  Newton stops when a step gains less than
    `newton_tol` (nats); L-BFGS-B at `ftol` (relative change of the bound), `gtol` (largest
    projected gradient component) or its budget.

    Why Newton: the bound is badly conditioned in log lambda (a change of lambda_i moves the
    noise at every point within a g-lengthscale, through Kg), so L-BFGS-B needed 20
    lambda-only and 40-60 joint iterations (61 evaluations at n = 100, 7.4x the GP's fit
    time); the Gauss-Newton step, whose curvature is the Fisher information of the noise
    plus the KL's, gets within ~1 nat of the lambda optimum in 4-6 steps.  Measured
    figures: docs/learner.md.

    mu0_offset: the authors' start mu0 = log(GP noise variance) - 2.5 (default).  Measured on
    8 seeds of Goldberg/Williams/Yuan: same bound and NLPD as 0.0 on Goldberg and Yuan,
    slightly better on Williams (bound 83.1 vs 82.0, noise-std RMSE 0.073 vs 0.082).
    """

    def __init__(
        self,
        fixed_hyperparameters: VHGPHyperparameters | None = None,
        max_iter: int = 12,
        newton_iter: int = 8,
        warm_iter: int = 6,
        warm_newton_iter: int = 3,
        newton_tol: float = 0.05,
        ftol: float = 1e-5,
        gtol: float = 1e-3,
        gp_restarts: int = 1,
        g_variance0: float = 1.0,
        mu0_offset: float = -2.5,
        lengthscale_range: tuple[float, float] = (0.02, 50.0),
        g_lengthscale_range: tuple[float, float] | None = None,
        g_variance_range: tuple[float, float] = (1e-3, 50.0),
        jitter: float = 1e-8,
    ) -> None:
        if fixed_hyperparameters is not None and not isinstance(fixed_hyperparameters, VHGPHyperparameters):
            raise CriticInputError("fixed_hyperparameters must be a VHGPHyperparameters")
        if not (0 < lengthscale_range[0] < lengthscale_range[1]):
            raise CriticInputError("lengthscale_range must be 0 < lo < hi")
        self._fixed = fixed_hyperparameters
        self._max_iter = int(max_iter)
        self._newton_iter = int(newton_iter)
        self._warm_iter = int(warm_iter)
        self._warm_newton_iter = int(warm_newton_iter)
        self._newton_tol = float(newton_tol)
        self._options = {"ftol": float(ftol), "gtol": float(gtol)}
        self._gp_restarts = int(gp_restarts)
        self._g_variance0 = float(g_variance0)
        self._mu0_offset = float(mu0_offset)
        self._ls_range = (float(lengthscale_range[0]), float(lengthscale_range[1]))
        g_ls = lengthscale_range if g_lengthscale_range is None else g_lengthscale_range
        if not (0 < g_ls[0] <= g_ls[1]) or not (0 < g_variance_range[0] <= g_variance_range[1]):
            raise CriticInputError("g ranges must be 0 < lo <= hi (lo == hi: held fixed)")
        self._g_ls_range = (float(g_ls[0]), float(g_ls[1]))
        self._g_var_range = (float(g_variance_range[0]), float(g_variance_range[1]))
        self._jitter = float(jitter)
        self._fitted = False
        self.n_evaluations = 0

    # ---------------------------------------------------------------- fitting
    def _bounds(self, X: np.ndarray) -> np.ndarray:
        """Box for p in standardised units: (n + 2d + 3, 2)."""
        n, d = X.shape
        span = input_spans(X)
        ell = np.column_stack([np.log(self._ls_range[0] * span), np.log(self._ls_range[1] * span)])
        ell_g = np.column_stack([np.log(self._g_ls_range[0] * span), np.log(self._g_ls_range[1] * span)])
        rows = [np.tile([-10.0, 10.0], (n, 1)), ell, [[math.log(1e-4), math.log(1e2)]], ell_g]
        rows += [[[math.log(self._g_var_range[0]), math.log(self._g_var_range[1])]], [[-18.0, 4.0]]]
        return np.vstack(rows)

    def _fixed_kernel(self, d: int, std: Standardisation) -> np.ndarray:
        h = self._fixed
        assert h is not None
        if len(h.f_lengthscales) != d:
            raise CriticInputError(f"fixed hyperparameters have {len(h.f_lengthscales)} lengthscales, X has d={d}")
        s2 = std.scale**2
        return np.concatenate(
            [
                np.log(h.f_lengthscales),
                [math.log(h.f_variance / s2)],
                np.log(h.g_lengthscales),
                [math.log(h.g_variance), h.g_mean - math.log(s2)],
            ]
        )

    def _optimise(
        self, p0: np.ndarray, X: np.ndarray, ys: np.ndarray, bounds: np.ndarray, iters: int, start: BoundState | None = None
    ) -> np.ndarray:
        """L-BFGS-B on all coordinates from p0 inside the box, at most `iters` iterations.
        start: the bound's state at p0 if the caller has it (saves one evaluation)."""
        if iters <= 0:
            return p0
        cache: dict[str, Any] = {}
        p = np.clip(p0, bounds[:, 0], bounds[:, 1])
        known = {"p": p.copy(), "st": start if start is not None and np.array_equal(p, p0) else None}

        def obj(q: np.ndarray) -> tuple[float, np.ndarray]:
            st = known["st"]
            if st is not None and np.array_equal(q, known["p"]):
                known["st"] = None
                return -st.F, -gradient(st, q, X, ys)
            self.n_evaluations += 1
            v, gr = vhgp_bound(q, X, ys, self._jitter, grad="all", cache=cache)
            assert gr is not None
            return -v, -gr

        res = minimize(obj, p, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": iters, **self._options})
        return np.asarray(res.x)

    def _newton(
        self, p0: np.ndarray, X: np.ndarray, ys: np.ndarray, bounds: np.ndarray, iters: int, with_mu0: bool
    ) -> tuple[np.ndarray, BoundState | None]:
        """Gauss-Newton steps in (lambda, mu0) at fixed kernel hyperparameters (bound.newton_step)
        with a backtracking line search inside the box; stops when the quadratic model
        predicts a gain below newton_tol, or after `iters` steps.  Returns p and the bound's
        state there (None if it cannot be evaluated)."""
        n = X.shape[0]
        p = np.clip(p0, bounds[:, 0], bounds[:, 1])
        lam_lo, lam_hi = math.exp(bounds[0, 0]), math.exp(bounds[0, 1])
        cache: dict[str, Any] = {}
        st = evaluate(p, X, ys, self._jitter, cache)
        self.n_evaluations += 1
        for _ in range(iters):
            step = None if st is None else newton_step(st, ys, with_mu0, lam_lo)
            if st is None or step is None or 0.5 * step.decrement < self._newton_tol:
                break
            lam, t = np.exp(p[:n]), 1.0
            while t >= 1.0 / 32.0:
                q = p.copy()
                q[:n] = np.log(np.clip(lam + t * step.d_lambda, lam_lo, lam_hi))
                q[-1] = min(max(p[-1] + t * step.d_mu0, bounds[-1, 0]), bounds[-1, 1])
                trial = evaluate(q, X, ys, self._jitter, cache)
                self.n_evaluations += 1
                if trial is not None and trial.F > st.F:
                    gain = trial.F - st.F
                    p, st = q, trial
                    break
                t *= 0.5
            else:
                break
            if gain < self._newton_tol:
                break
        return p, st

    def fit(self, X: object, y: object, warm_start: VHGPParams | None = None) -> "VHGP":
        """Fit to X (n, d), y (n,), n >= 3.

        warm_start: optimiser coordinates of a previous fit to start from; its log_lambda
        must have length n (the caller aligns it to the rows of X), or be empty (-> 1/2).
        """
        Xa, ya = check_xy(X, y, min_points=3)
        n, d = Xa.shape
        std = Standardisation.of(ya)
        ys = std.apply(ya)
        bounds = self._bounds(Xa)
        self.n_evaluations = 0
        with single_threaded_blas():
            if warm_start is not None:
                kern = np.asarray(warm_start.kernel, float)
                if kern.shape != (2 * d + 3,):
                    raise CriticInputError(f"warm_start.kernel must have shape ({2 * d + 3},)")
                loglam = np.asarray(warm_start.log_lambda, float)
                if loglam.size == 0:
                    loglam = np.full(n, math.log(0.5))
                if loglam.shape != (n,):
                    raise CriticInputError(f"warm_start.log_lambda must have shape ({n},)")
            else:
                loglam = np.full(n, math.log(0.5))
            if self._fixed is not None:
                kern = self._fixed_kernel(d, std)
                p = np.concatenate([loglam, kern])
                p, _ = self._newton(p, Xa, ys, bounds, max(self._newton_iter, self._max_iter), with_mu0=False)
            elif warm_start is not None:
                p = np.concatenate([loglam, kern])
                p, st = self._newton(p, Xa, ys, bounds, self._warm_newton_iter, with_mu0=True)
                p = self._optimise(p, Xa, ys, bounds, self._warm_iter, st)
            else:
                gp = GP(n_restarts=self._gp_restarts, lengthscale_range=self._ls_range).fit(Xa, ya)
                h = gp.hyperparameters
                s2 = std.scale**2
                log_ell = np.log(h.lengthscales)
                kern = np.concatenate(
                    [
                        log_ell,
                        [math.log(h.signal_variance / s2)],
                        log_ell,
                        [
                            math.log(min(max(self._g_variance0, self._g_var_range[0]), self._g_var_range[1])),
                            math.log(h.noise_variance / s2) + self._mu0_offset,
                        ],
                    ]
                )
                p = np.concatenate([loglam, kern])
                p, st = self._newton(p, Xa, ys, bounds, self._newton_iter, with_mu0=True)
                p = self._optimise(p, Xa, ys, bounds, self._max_iter, st)
            self._set_state(Xa, ya, std, p)
        return self

    @classmethod
    def from_params(cls, X: object, y: object, params: VHGPParams, jitter: float = 1e-8) -> "VHGP":
        """Rebuild a fitted model from stored coordinates without optimising (exact)."""
        Xa, ya = check_xy(X, y, min_points=3)
        n, d = Xa.shape
        if params.log_lambda.shape != (n,) or params.kernel.shape != (2 * d + 3,):
            raise CriticInputError("params do not match the shape of X")
        model = cls(jitter=jitter)
        with single_threaded_blas():
            model._set_state(Xa, ya, Standardisation.of(ya), np.concatenate([params.log_lambda, params.kernel]))
        return model

    def _set_state(self, X: np.ndarray, y: np.ndarray, std: Standardisation, p: np.ndarray) -> None:
        n, d = X.shape
        ys = std.apply(y)
        value, _ = vhgp_bound(p, X, ys, self._jitter, grad="none")
        if value <= -BAD:
            raise FitError("VHGP: no numerically valid parameters found")
        loglam, lf, lsf, lg, lsg, mu0 = unpack(p, n, d)
        lam = np.exp(loglam)
        s = np.sqrt(lam)
        Kg = se_ard(X, X, lg, lsg)
        B = s[:, None] * Kg * s[None, :]
        B[np.diag_indices(n)] += 1.0
        LB = la.cholesky(B)
        V = la.tri_solve(LB, s[:, None] * Kg)
        beta = lam - 0.5
        R = np.exp(Kg @ beta + mu0 - 0.5 * (np.diagonal(Kg) - (V * V).sum(0)))
        K = se_ard(X, X, lf, lsf)
        K[np.diag_indices(n)] += R + self._jitter
        LK = la.cholesky(K)
        self._X, self._y, self._std, self._p = X, y, std, p.copy()
        self._LB, self._LK, self._s, self._beta, self._R = LB, LK, s, beta, R
        self._alpha = la.chol_solve(LK, ys)
        self._bound_std = value
        self._fitted = True

    # ---------------------------------------------------------------- accessors
    def _check(self) -> None:
        if not self._fitted:
            raise NotFittedError("VHGP.fit() has not been called")

    def bound(self) -> float:
        """Fitted MV bound, in the units of y (log density units; standardisation undone)."""
        self._check()
        return self._bound_std - self._X.shape[0] * math.log(self._std.scale)

    @property
    def params(self) -> VHGPParams:
        self._check()
        n = self._X.shape[0]
        return VHGPParams(self._p[:n].copy(), self._p[n:].copy())

    @property
    def hyperparameters(self) -> VHGPHyperparameters:
        self._check()
        n, d = self._X.shape
        _, lf, lsf, lg, lsg, mu0 = unpack(self._p, n, d)
        s2 = self._std.scale**2
        return VHGPHyperparameters(
            tuple(float(v) for v in np.exp(lf)),
            float(math.exp(lsf) * s2),
            tuple(float(v) for v in np.exp(lg)),
            float(math.exp(lsg)),
            float(mu0 + math.log(s2)),
        )

    @property
    def X(self) -> np.ndarray:
        """Training inputs (n, d) (a read-only view)."""
        self._check()
        return read_only(self._X)

    @property
    def y(self) -> np.ndarray:
        """Training outputs (n,) in the units of the data (a read-only view)."""
        self._check()
        return read_only(self._y)

    def loo(self, noise_floor: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Leave-one-out residuals of the posterior mean and their variance without the noise,
        both (n,) in the units of y: e_i = [K^-1 y]_i / [K^-1]_ii and
        v_i = 1 / [K^-1]_ii - R'_ii, with K = Kf + R' + jitter (standardised units) and
        R' = max(R, noise_floor): a fit whose noise collapsed (R -> 0, f through every
        point) would otherwise give residuals at the level of round-off."""
        self._check()
        n, d = self._X.shape
        _, lf, lsf, _, _, _ = unpack(self._p, n, d)
        Rf = np.maximum(self._R, noise_floor)
        with single_threaded_blas():
            K = se_ard(self._X, self._X, lf, lsf)
            K[np.diag_indices(n)] += Rf + self._jitter
            L = la.cholesky(K)
            if L is None:  # pragma: no cover - K is better conditioned than the fitted one
                raise FitError("VHGP: leave-one-out matrix is not positive definite")
            Kinv = la.chol_inverse(L)
        dinv = np.diagonal(Kinv)
        a = Kinv @ self._std.apply(self._y)
        sc = self._std.scale
        return sc * a / dinv, sc * sc * np.maximum(1.0 / dinv - Rf, 0.0)

    # ---------------------------------------------------------------- prediction
    def _kernels(self, Xt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, d = self._X.shape
        _, lf, lsf, lg, lsg, _ = unpack(self._p, n, d)
        return se_ard(Xt, self._X, lf, lsf), se_ard(Xt, self._X, lg, lsg)

    def _posterior(self, Xt: np.ndarray) -> tuple[VHGPPrediction, np.ndarray, np.ndarray]:
        """Posterior of f and g at checked inputs Xt (m, d), with the cross-kernels (m, n)
        of f and g it used (the gradient reuses them)."""
        n, d = self._X.shape
        _, _, lsf, _, lsg, mu0 = unpack(self._p, n, d)
        sc = self._std.scale
        Kfs, Kgs = self._kernels(Xt)
        Vf = la.tri_solve(self._LK, Kfs.T)
        Vg = la.tri_solve(self._LB, self._s[:, None] * Kgs.T)
        pred = VHGPPrediction(
            f_mean=self._std.mean + sc * (Kfs @ self._alpha),
            f_var=sc * sc * np.maximum(math.exp(lsf) - (Vf * Vf).sum(0), 0.0),
            g_mean=Kgs @ self._beta + mu0 + 2.0 * math.log(sc),
            g_var=np.maximum(math.exp(lsg) - (Vg * Vg).sum(0), 0.0),
        )
        return pred, Kfs, Kgs

    def predict(self, Xs: object) -> VHGPPrediction:
        """Posterior of f and g at Xs (m, d)."""
        self._check()
        Xt = check_xs(Xs, self._X.shape[1])
        with single_threaded_blas():
            return self._posterior(Xt)[0]

    def predict_with_gradient(self, Xs: object) -> tuple[VHGPPrediction, VHGPPredictionGradient]:
        """predict(Xs) and the derivatives of its fields with respect to the inputs, (m, d)."""
        self._check()
        n, d = self._X.shape
        Xt = check_xs(Xs, d)
        _, lf, _, lg, _, _ = unpack(self._p, n, d)
        sc = self._std.scale
        with single_threaded_blas():
            pred, Kfs, Kgs = self._posterior(Xt)
            dKf = se_ard_input_grad(Xt, self._X, Kfs, lf)  # (m, n, d)
            dKg = se_ard_input_grad(Xt, self._X, Kgs, lg)
            Uf = la.chol_solve(self._LK, Kfs.T)  # (n, m) = K^-1 kf*
            Ug = self._s[:, None] * la.chol_solve(self._LB, self._s[:, None] * Kgs.T)  # A kg*
        grad = VHGPPredictionGradient(
            f_mean=sc * np.einsum("mnd,n->md", dKf, self._alpha),
            f_var=-2.0 * sc * sc * np.einsum("mnd,nm->md", dKf, Uf),
            g_mean=np.einsum("mnd,n->md", dKg, self._beta),
            g_var=-2.0 * np.einsum("mnd,nm->md", dKg, Ug),
        )
        return pred, grad
