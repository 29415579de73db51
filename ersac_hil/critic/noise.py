"""Log-linear noise model of a local neighbourhood: g(x) = log r(x)^2 = a + b'(x - c).

The local critic's r~ and its slope come from this model when `CriticConfig.noise_model` is
"loglinear" (the default).  It is the noise process g of the VHGP with a linear kernel
instead of a squared exponential one, fitted by MAP with a Laplace posterior, on the VHGP's
leave-one-out residuals:

    e_i ~ N(0, exp(a + b'(x_i - c)) + v_i),   b ~ N(0, diag(s^2)),   a ~ N(log mean(e^2), 3^2),

e_i the leave-one-out residual of the VHGP mean at x_i and v_i the leave-one-out variance of
that mean (both closed form from the VHGP's K = Kf + R: e_i = [K^-1 y]_i / [K^-1]_ii,
v_i = 1 / [K^-1]_ii - R_ii).  Leave-one-out residuals do not shrink where the mean overfits,
and v_i keeps the uncertainty of the mean out of the noise.  The posterior of (a, b) is
Gaussian (Laplace, expected information), so at x

    g_mean(x) = z' p,   g_var(x) = z' C z,   z = [1, x - c],

and r~(x) = exp(g_mean / 2 + g_var / 4) exactly as for the VHGP's g.  A linear model must not
extrapolate: x - c is clipped to the data's box widened by half its extent on each side (the
slope is zero beyond).

Why (bench/critic.py, docs/learner.md): on 10-60 points in an epsilon ball the VHGP's g is
pulled flat by its hyperparameter fit (the bound's Occam term; median slope ratio of r~ 0.1-0.3
on most problems), while a log-linear g on that ball is close to what the data can
determine at all (the Cramer-Rao bound of the slope is computed for this very model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize

from .errors import FitError

if TYPE_CHECKING:
    from .prior import CriticPrior


#: Cap of the posterior variance of g used in r~ = exp(g_mean/2 + g_var/4) and the predictive
#: density (the VHGP's g has prior variance >= 1, CriticConfig.g_variance_min). Where the
#: residuals say nothing (every v_i >> exp g) the posterior is the prior, whose slope term
#: alone reached g_var ~ 60 in a bracing demo update: r~ 6.5e6 against a spread of ~6.
G_VAR_MAX = 1.0


@dataclass(frozen=True, eq=False)
class LogLinearNoise:
    """centre c (d,), coef p = [a, b] (d + 1,), cov C (d + 1, d + 1): posterior of (a, b).
    With ``prior`` (a simulator's landscape, critic/prior.py) g(x) = o(x) + a + b'(x - c),
    o = 2 log of the simulated std: the linear part corrects the simulator's noise."""

    centre: np.ndarray
    coef: np.ndarray
    cov: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    prior: CriticPrior | None = None
    #: negative log posterior density of the residuals at the MAP (in their own units)
    nll: float = math.nan

    def _z(self, Xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inside = (Xs >= self.lo) & (Xs <= self.hi)
        return np.column_stack([np.ones(Xs.shape[0]), np.clip(Xs, self.lo, self.hi) - self.centre]), inside

    def predict(self, Xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(g_mean, g_var) at Xs (m, d), each (m,); g_var at most G_VAR_MAX."""
        Z, _ = self._z(Xs)
        g = Z @ self.coef
        if self.prior is not None:
            g = g + self.prior.log_var_at(Xs)[0]
        return g, np.clip(np.einsum("ij,jk,ik->i", Z, self.cov, Z), 0.0, G_VAR_MAX)

    def gradient(self, Xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d g_mean / dx, d g_var / dx) at Xs (m, d), each (m, d) (0 where clipped)."""
        Z, inside = self._z(Xs)
        capped = (np.einsum("ij,jk,ik->i", Z, self.cov, Z) >= G_VAR_MAX)[:, None]
        dg = self.coef[1:] * inside
        if self.prior is not None:
            dg = dg + self.prior.log_var_at(Xs)[1]
        return dg, 2.0 * (Z @ self.cov[:, 1:]) * inside * ~capped


def pseudo_count(n: int, d: int) -> int:
    """Pseudo-residuals of the small-sample noise prior for n residuals in d dimensions:
    max(0, 2 (d + 1) - n) (see fit_log_linear)."""
    return max(0, 2 * (d + 1) - int(n))


def fit_log_linear(
    X: np.ndarray, e: np.ndarray, v: np.ndarray, slope_prior_std: np.ndarray, spread: float = 0.0, pseudo: float = 0.0,
    prior: CriticPrior | None = None,
) -> LogLinearNoise:
    """MAP and Laplace posterior of g = a + b'(x - c), c = mean of X.

    X (n, d) inputs, e (n,) residuals, v (n,) >= 0 known extra variance of each residual,
    slope_prior_std (d,) prior std of b.  spread, pseudo: a small-sample prior on the level,
    `pseudo` residuals of variance `spread` at the centre c (the conjugate scaled-inverse-chi^2
    prior on exp(a) with `pseudo` degrees of freedom); they only inform a, and at the optimum
    exp(g_mean(c)) = exp(a) >= pseudo spread / (pseudo + n) whatever the residuals (each real
    residual's term in d nll / da is at most 1/2, and a's own prior is centred on the pooled
    level, which is above that bound).  prior: g = o(x) + a + b'(x - c) with o the simulator's
    log variance (the residuals and the pseudo-residuals are read relative to it).  Raises
    FitError if no finite optimum is found."""
    n, d = X.shape
    c = X.mean(0)
    U = X - c
    prec = 1.0 / slope_prior_std**2
    # relative to the simulator's log variance o(x): e_i e^(-o_i/2), v_i e^(-o_i) (exact)
    jacobian = 0.0
    if prior is not None:
        o = prior.log_var_at(X)[0]
        e, v, jacobian = e * np.exp(-0.5 * o), v * np.exp(-o), 0.5 * float(np.sum(o))
        spread = spread * math.exp(-float(prior.log_var_at(c[None, :])[0][0]))
    e2 = e * e
    m0 = float(pseudo) if spread > 0 else 0.0
    S = float(spread)
    a0 = math.log(max((float(np.sum(e2)) + m0 * S) / (n + m0), 1e-300))
    prec_a = 1.0 / 9.0

    def nll(p: np.ndarray) -> tuple[float, np.ndarray]:
        with np.errstate(over="ignore"):
            s = np.exp(p[0] + U @ p[1:])
            pseudo_term = m0 * S * math.exp(-p[0]) if m0 > 0 else 0.0
        tot = s + v
        if not np.all(np.isfinite(tot)) or np.any(tot <= 0) or not math.isfinite(pseudo_term):
            return 1e300, np.zeros_like(p)
        val = 0.5 * float(np.sum(np.log(tot) + e2 / tot) + np.sum(prec * p[1:] ** 2) + prec_a * (p[0] - a0) ** 2)
        val += 0.5 * (m0 * p[0] + pseudo_term)
        w = 0.5 * (s / tot) * (1.0 - e2 / tot)
        da = w.sum() + prec_a * (p[0] - a0) + 0.5 * (m0 - pseudo_term)
        return val, np.concatenate([[da], U.T @ w + prec * p[1:]])

    level = float(np.sum(np.maximum(e2 - v, 0.0)) + m0 * S) / (n + m0)
    level = max(level, 1e-3 * float(np.mean(e2)) + 1e-300)
    p0 = np.concatenate([[math.log(level)], np.zeros(d)])
    res = minimize(nll, p0, jac=True, method="L-BFGS-B", options={"maxiter": 200})
    p = res.x
    if not (np.all(np.isfinite(p)) and res.fun < 1e300):
        raise FitError("log-linear noise model: no finite optimum")
    s = np.exp(p[0] + U @ p[1:])
    w = s / (s + v)
    Z = np.column_stack([np.ones(n), U])
    H = 0.5 * (Z * (w * w)[:, None]).T @ Z
    H[1:, 1:] += np.diag(prec)
    H[0, 0] += prec_a + 0.5 * m0
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError as exc:  # pragma: no cover - H is positive definite
        raise FitError(f"log-linear noise model: singular information ({exc})") from exc
    extent = X.max(0) - X.min(0)
    return LogLinearNoise(c, p, 0.5 * (cov + cov.T), X.min(0) - 0.5 * extent, X.max(0) + 0.5 * extent, prior,
                          float(res.fun) + jacobian)
