"""Local critic: a VHGP fitted to the observations near theta.

Neighbourhood of theta: every observation within Euclidean distance `epsilon` (KD-tree ball
query, parameter units); if fewer than `min_neighbours` are inside, the `min_neighbours`
nearest instead; if more than `max_neighbours`, the `max_neighbours` nearest of the ball.
Indices are sorted, so a neighbourhood is a deterministic function of the data and theta.

On that neighbourhood a VHGP gives, at any query point x,

    J~(x) = f_mean(x)                                  (posterior mean of the cost)
    r~(x) = sqrt(E_q[exp g(x)]) = exp(g_mean(x) / 2 + g_var(x) / 4)
            (square root of the posterior-expected noise variance: the critic's estimate
             of the standard deviation of a single episode's cost at x; it excludes the
             uncertainty f_var about the mean)
    F~(x) = J~(x) + kappa r~(x),  grad F~ = grad J~ + kappa r~ (grad g_mean / 2 + grad g_var / 4).

With `CriticConfig.noise_model` "loglinear" (the default) g_mean and g_var in r~ come from a
log-linear noise model fitted to the VHGP's leave-one-out residuals (critic/noise.py)
instead of the VHGP's own g; J~ is always the VHGP's posterior mean.

Fits are cached by content (neighbourhood indices, their inputs and costs): a neighbourhood
that has not changed is never refitted, and re-weighting the costs invalidates exactly the
fits whose costs changed.  A fit can be warm-started from another fit (`LocalFit`): kernel
hyperparameters are copied and each shared observation keeps its variational lambda.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.spatial import cKDTree

from .errors import CriticInputError
from .noise import LogLinearNoise, fit_log_linear, pseudo_count
from .prior import CriticPrior
from .vhgp import VHGP, VHGPHyperparameters, VHGPParams, VHGPPrediction, VHGPPredictionGradient

MIN_FIT_POINTS = 3
#: "loglinear": r~ from a log-linear noise model on the VHGP's leave-one-out residuals of a
#: local fit (critic/noise.py); "vhgp": r~ from the VHGP's own noise process g.
NOISE_MODELS = ("loglinear", "vhgp")


class CriticData(Protocol):
    """What the critic reads: append-only points and their current costs."""

    @property
    def points(self) -> np.ndarray:  # (N, d); rows never change once added
        ...

    @property
    def costs(self) -> np.ndarray:  # (N,); may change as a whole (re-weighting)
        ...


@dataclass(frozen=True)
class CriticConfig:
    """epsilon: ball radius (parameter units); min/max_neighbours: see module doc;
    VHGP budgets: cold_iter (stage 2 of a cold fit), warm_iter; fixed_hyperparameters:
    fixed-hyperparameter mode (only lambda is optimised); cache_size: fits kept.

    g_variance_min, g_lengthscale_max: floor of the prior variance of the log-noise process
    g and cap of its lengthscales (as a multiple of the neighbourhood's extent).  Without
    them (1e-3 and 50) the bound's Occam term makes a 10-40 point neighbourhood collapse to
    a flat noise function (r~ slope 0), and warm starts keep every later fit there: measured
    on the 1-D bracing-like problem the critic's slope of r~ was 0.00x the truth along ERSAC
    runs; with the defaults (1.0, 2.0) it was ~0.5-0.7x and the kappa = 2 runs settled at
    the risk-sensitive optimum instead of drifting past it.

    lengthscale_min: floor of every lengthscale (f and g), as a multiple of
    sqrt(d) x the neighbourhood's extent per input.  Below it the kernel is white noise on
    the scale of the neighbourhood, and a white-noise f explains the noise more cheaply than
    g does (no KL term): in 7-D with 60 neighbours the fits settled at f lengthscales of
    0.01-0.1 and r~ = 0.004 (truth 0.1-0.5).  The sqrt(d) is because neighbour distances grow
    with sqrt(d) for the same per-input spread.

    noise_model: where r~ and its slope come from in a neighbourhood fit. "loglinear"
    (default): g = log r^2 = a + b'(x - c) fitted by MAP/Laplace to the VHGP's leave-one-out
    residuals (critic/noise.py), slope prior std noise_slope_prior / extent per input, opened
    up linearly from d + 1 to 5 (d + 1) points.  "vhgp": the VHGP's own g (the paper's
    critic).  Measured with bench/critic.py on 7 problems at 30-60 points: the VHGP's g gave
    median slope ratios 0.1-0.5 on 5 of 7 problems (the hyperparameter fit flattens g), the
    log-linear model 0.6-1.2, with the same NLPD against a homoscedastic GP (docs/learner.md).
    Wide selection fits (learner.selection) keep the VHGP's g.

    g_variance_max, g_lengthscale_min: the other ends of the g hyperparameter boxes (equal
    ends hold a hyperparameter fixed); measured alternatives, not used by default.

    small_n_prior: below 2 (d + 1) points the log-linear noise level is pooled with
    2 (d + 1) - n pseudo-residuals at the sample variance of the neighbourhood's costs (a
    conjugate prior; r~ at the neighbourhood's centre is then at least
    sqrt((2 (d + 1) - n) / (2 (d + 1))) x their std).  d + 1 points fit any local linear
    trend exactly, so below twice that the residuals of an ARD mean cannot tell noise from
    structure: measured on 5 stored lifting runs (7-D, 10 neighbours at every update) r~
    was 0.8-3 where the costs were 4.5 or 38 (std ~15), eta / r~ sat at its clip and single
    updates moved theta by up to 35 sigma before the move guard (docs/learner.md).
    clip_mean: the learner's TD baseline J~(theta) is clipped to the range of the costs of
    the fit it comes from (ERSAC's update): theta is the centre of its own perturbations, so
    a mean there beyond every cost around it is the ringing of a near-interpolating fit
    between two cost modes (measured on lifting: J~ -42.8 where every cost was 4-45), not
    information.  Predictions elsewhere are not clipped (a trend may leave the costs' range
    legitimately away from the data: clipping every prediction cost Branin 1-5 points of
    coverage in bench/critic.py).  False for both is the previous critic.

    cold_every: the learner's update fits are warm-started from the previous one; every
    `cold_every`-th also runs a cold fit (the two-stage recipe) and keeps whichever has the
    higher bound.  A warm chain can sit on a plateau forever: with the noise R -> 0 the
    gradients with respect to lambda and mu0 vanish (both are proportional to R); 15
    points in 7-D reach that plateau on the first fit.

    prior: a simulator's prediction of the cost (critic/prior.py), the residual model: the
    VHGP fits the costs minus the simulated mean, the log-linear noise model the log variance
    relative to the simulated one, and every prediction adds them back. With a prior, wide
    selection fits take the log-linear noise model too (the simulator's shape is what the
    prior is for). None (default): the critic sees the robot's episodes only.
    prior_slope: with a prior, the slope prior std of the log-linear correction is
    prior_slope / extent instead of noise_slope_prior / extent: the correction of a
    simulator's noise shape, not the shape itself (with 10 / extent 15 points below the
    simulated rise of the noise cancelled it: r~ 4x too small beyond them)."""

    epsilon: float
    min_neighbours: int = 10
    max_neighbours: int = 60
    cold_iter: int = 12
    warm_iter: int = 6
    fixed_hyperparameters: VHGPHyperparameters | None = None
    g_variance_min: float = 1.0
    g_lengthscale_max: float = 2.0
    lengthscale_min: float = 0.25
    cold_every: int = 10
    cache_size: int = 32
    g_variance_max: float = 50.0
    g_lengthscale_min: float | None = None
    noise_model: str = "loglinear"
    noise_slope_prior: float = 10.0
    small_n_prior: bool = True
    clip_mean: bool = True
    prior: CriticPrior | None = None
    prior_slope: float = 2.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.epsilon) and self.epsilon > 0):
            raise CriticInputError(f"epsilon must be finite and > 0, got {self.epsilon}")
        if self.min_neighbours < MIN_FIT_POINTS:
            raise CriticInputError(f"min_neighbours must be >= {MIN_FIT_POINTS}")
        if self.max_neighbours < self.min_neighbours:
            raise CriticInputError("max_neighbours must be >= min_neighbours")
        if not (math.isfinite(self.g_variance_min) and 0 < self.g_variance_min <= self.g_variance_max <= 50.0):
            raise CriticInputError("need 0 < g_variance_min <= g_variance_max <= 50")
        if self.g_lengthscale_min is not None and not (0 < self.g_lengthscale_min <= self.g_lengthscale_max):
            raise CriticInputError("need 0 < g_lengthscale_min <= g_lengthscale_max")
        if not (math.isfinite(self.lengthscale_min) and 0 < self.lengthscale_min < self.g_lengthscale_max):
            raise CriticInputError("need 0 < lengthscale_min < g_lengthscale_max (finite)")
        if self.noise_model not in NOISE_MODELS:
            raise CriticInputError(f"noise_model must be one of {NOISE_MODELS}, got {self.noise_model!r}")
        if not (math.isfinite(self.noise_slope_prior) and self.noise_slope_prior > 0):
            raise CriticInputError("noise_slope_prior must be finite and > 0")
        if not (isinstance(self.small_n_prior, bool) and isinstance(self.clip_mean, bool)):
            raise CriticInputError("small_n_prior and clip_mean must be booleans")
        if not (math.isfinite(self.prior_slope) and self.prior_slope > 0):
            raise CriticInputError("prior_slope must be finite and > 0")
        if self.prior is not None and not isinstance(self.prior, CriticPrior):
            raise CriticInputError("prior must be a CriticPrior or None")
        if self.cold_every < 0:
            raise CriticInputError("cold_every must be >= 0 (0: never)")
        if self.cold_iter < 0 or self.warm_iter < 0 or self.cache_size < 1:
            raise CriticInputError("iteration budgets must be >= 0 and cache_size >= 1")

    def to_dict(self) -> dict[str, Any]:
        fixed = self.fixed_hyperparameters
        return {**({} if self.prior is None else {"prior": self.prior.to_dict(), "prior_slope": self.prior_slope}),
            "epsilon": self.epsilon,
            "min_neighbours": self.min_neighbours,
            "max_neighbours": self.max_neighbours,
            "cold_iter": self.cold_iter,
            "warm_iter": self.warm_iter,
            "fixed_hyperparameters": None
            if fixed is None
            else {
                "f_lengthscales": list(fixed.f_lengthscales),
                "f_variance": fixed.f_variance,
                "g_lengthscales": list(fixed.g_lengthscales),
                "g_variance": fixed.g_variance,
                "g_mean": fixed.g_mean,
            },
            "g_variance_min": self.g_variance_min,
            "g_lengthscale_max": self.g_lengthscale_max,
            "lengthscale_min": self.lengthscale_min,
            "cold_every": self.cold_every,
            "cache_size": self.cache_size,
            "g_variance_max": self.g_variance_max,
            "g_lengthscale_min": self.g_lengthscale_min,
            "noise_model": self.noise_model,
            "noise_slope_prior": self.noise_slope_prior,
            "small_n_prior": self.small_n_prior,
            "clip_mean": self.clip_mean,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "CriticConfig":
        data = dict(data)
        fixed = data.pop("fixed_hyperparameters", None)
        prior = data.pop("prior", None)
        if fixed is not None:
            fixed = VHGPHyperparameters(
                tuple(fixed["f_lengthscales"]),
                fixed["f_variance"],
                tuple(fixed["g_lengthscales"]),
                fixed["g_variance"],
                fixed["g_mean"],
            )
        return cls(fixed_hyperparameters=fixed, prior=None if prior is None else CriticPrior.from_dict(prior), **data)


@dataclass(frozen=True, eq=False)
class CriticEstimate:
    """The critic at one point x (d,): J~, r~, F~ = J~ + kappa r~ and their gradients (d,).

    J_var is the posterior variance of J~ (uncertainty about the mean, not the noise);
    g_var the posterior variance of the log noise variance g (var r~ ~ r~^2 g_var / 4)."""

    x: np.ndarray
    J: float
    r: float
    F: float
    kappa: float
    J_var: float
    g_var: float
    grad_J: np.ndarray
    grad_r: np.ndarray
    grad_F: np.ndarray
    n_neighbours: int


@dataclass(frozen=True, eq=False)
class LocalFit:
    """A VHGP fitted to the observations `ids` (sorted store indices, (n,)); with `noise`, the
    noise process g (r~ and its slope) comes from that log-linear model instead. With
    `prior` (CriticConfig.prior) the VHGP was fitted to the costs minus the simulated mean,
    which every prediction adds back; `costs` are the costs themselves."""

    ids: np.ndarray
    model: VHGP
    warm_started: bool = field(default=False)
    noise: LogLinearNoise | None = None
    prior: CriticPrior | None = None
    y: np.ndarray | None = None

    @property
    def costs(self) -> np.ndarray:
        """The costs this fit was fitted to (n,)."""
        return self.model.y if self.y is None else self.y

    def _mean(self, Xa: np.ndarray, f_mean: np.ndarray) -> np.ndarray:
        return f_mean if self.prior is None else f_mean + self.prior.mean_at(Xa)[0]

    def predict(self, Xs: np.ndarray) -> VHGPPrediction:
        Xa = np.atleast_2d(np.asarray(Xs, dtype=float))
        pred = self.model.predict(Xs)
        if self.noise is None and self.prior is None:
            return pred
        g_mean, g_var = (pred.g_mean, pred.g_var) if self.noise is None else self.noise.predict(Xa)
        return VHGPPrediction(self._mean(Xa, pred.f_mean), pred.f_var, g_mean, g_var)

    def predict_with_gradient(self, Xs: np.ndarray) -> tuple[VHGPPrediction, VHGPPredictionGradient]:
        pred, grad = self.model.predict_with_gradient(Xs)
        if self.noise is None and self.prior is None:
            return pred, grad
        Xa = np.atleast_2d(np.asarray(Xs, dtype=float))
        g_mean, g_var = (pred.g_mean, pred.g_var) if self.noise is None else self.noise.predict(Xa)
        dg_mean, dg_var = (grad.g_mean, grad.g_var) if self.noise is None else self.noise.gradient(Xa)
        df = grad.f_mean if self.prior is None else grad.f_mean + self.prior.mean_at(Xa)[1]
        return (VHGPPrediction(self._mean(Xa, pred.f_mean), pred.f_var, g_mean, g_var),
                VHGPPredictionGradient(df, grad.f_var, dg_mean, dg_var))

    def estimate(self, x: np.ndarray, kappa: float = 0.0) -> CriticEstimate:
        """J~, r~, F~ and gradients at one point x (d,)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        pred, grad = self.predict_with_gradient(x[None, :])
        return _estimate(x, pred, grad, 0, kappa, self.ids.size)

    def estimate_many(self, Xs: np.ndarray, kappa: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised (J~, r~, F~) at Xs (m, d), each (m,)."""
        pred = self.predict(Xs)
        r = pred.noise_std
        return pred.f_mean, r, pred.f_mean + kappa * r

    def warm_start_for(self, ids: np.ndarray) -> VHGPParams:
        """VHGP coordinates to start a fit of `ids` from: shared observations keep their
        log lambda, new ones start at log(1/2); kernel hyperparameters are copied."""
        p = self.model.params
        pos = np.searchsorted(self.ids, ids)
        pos = np.minimum(pos, self.ids.size - 1)
        shared = self.ids[pos] == ids
        loglam = np.full(ids.size, math.log(0.5))
        loglam[shared] = p.log_lambda[pos[shared]]
        return VHGPParams(loglam, p.kernel)

    def compatible_with(self, ids: np.ndarray, costs: np.ndarray) -> bool:
        """True if every observation this fit shares with `ids` still has the cost the fit
        saw (costs (N,) the current costs of all observations)."""
        common, mine, _ = np.intersect1d(self.ids, ids, assume_unique=True, return_indices=True)
        return bool(np.array_equal(self.costs[mine], costs[common]))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record that rebuilds this fit exactly: indices, the costs it was fitted
        to (they may change later by re-weighting) and the VHGP coordinates."""
        return {
            "ids": [int(i) for i in self.ids],
            "y": [float(v) for v in self.costs],
            **({} if self.prior is None else {"prior_mean": True}),
            "params": self.model.params.to_dict(),
        }


def _estimate(
    x: np.ndarray, pred: VHGPPrediction, grad: VHGPPredictionGradient, i: int, kappa: float, n: int
) -> CriticEstimate:
    r = float(pred.noise_std[i])
    grad_r = r * (0.5 * grad.g_mean[i] + 0.25 * grad.g_var[i])
    J = float(pred.f_mean[i])
    return CriticEstimate(
        x=x.copy(),
        J=J,
        r=r,
        F=J + kappa * r,
        kappa=float(kappa),
        J_var=float(pred.f_var[i]),
        g_var=float(pred.g_var[i]),
        grad_J=grad.f_mean[i].copy(),
        grad_r=grad_r,
        grad_F=grad.f_mean[i] + kappa * grad_r,
        n_neighbours=n,
    )


class LocalCritic:
    """Neighbourhood selection, VHGP fitting with a content-keyed cache, estimates."""

    def __init__(self, data: CriticData, config: CriticConfig) -> None:
        self._data = data
        self.config = config
        self._tree: cKDTree | None = None
        self._tree_n = -1
        self._cache: OrderedDict[bytes, LocalFit] = OrderedDict()
        self.n_fits = 0

    # ------------------------------------------------------------ neighbourhoods
    def _kdtree(self) -> cKDTree:
        pts = self._data.points
        if self._tree is None or self._tree_n != pts.shape[0]:
            self._tree = cKDTree(pts)
            self._tree_n = pts.shape[0]
        return self._tree

    def neighbourhood(self, theta: np.ndarray, radius: float | None = None, max_points: int | None = None) -> np.ndarray:
        """Sorted store indices of the neighbourhood of theta (d,) (see module doc)."""
        pts = self._data.points
        N = pts.shape[0]
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if N == 0:
            return np.zeros(0, dtype=np.int64)
        if theta.shape != (pts.shape[1],):
            raise CriticInputError(f"theta must have shape ({pts.shape[1]},)")
        eps = self.config.epsilon if radius is None else float(radius)
        kmax = self.config.max_neighbours if max_points is None else int(max_points)
        kmin = min(self.config.min_neighbours, N)
        tree = self._kdtree()
        ids = np.asarray(tree.query_ball_point(theta, eps), dtype=np.int64)
        if ids.size < kmin:
            ids = self._nearest(tree, theta, kmin)
        elif ids.size > kmax:
            ids = self._nearest(tree, theta, kmax)
        return np.sort(ids)

    def nearest(self, theta: np.ndarray, k: int) -> np.ndarray:
        """Sorted indices of the k observations nearest to theta (d,) (all if fewer)."""
        N = self._data.points.shape[0]
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if N == 0:
            return np.zeros(0, dtype=np.int64)
        return np.sort(self._nearest(self._kdtree(), theta, min(int(k), N)))

    @property
    def data(self) -> CriticData:
        return self._data

    @staticmethod
    def _nearest(tree: cKDTree, theta: np.ndarray, k: int) -> np.ndarray:
        _, idx = tree.query(theta, k=k)
        return np.atleast_1d(np.asarray(idx, dtype=np.int64))

    # ------------------------------------------------------------ fitting
    def _key(self, ids: np.ndarray) -> bytes:
        return ids.tobytes() + self._data.points[ids].tobytes() + self._data.costs[ids].tobytes()

    def fit_ids(
        self, ids: np.ndarray, warm_start: LocalFit | None = None, use_cache: bool = True, also_cold: bool = False,
        local: bool = True,
    ) -> LocalFit:
        """VHGP on the observations `ids` (sorted, >= 3).

        With use_cache, an identical neighbourhood (same indices, inputs and costs) returns
        the cached fit whatever the warm start; without, the result depends only on the
        data, `warm_start` and `also_cold` (what the learner's update path needs for exact
        resume).  also_cold: with a warm start, also fit cold and keep the higher bound.
        local: a neighbourhood fit, whose noise comes from `config.noise_model`; False (a
        wide selection model) keeps the VHGP's own g.
        A warm start is ignored (cold fit) if the costs of the observations it shares with
        `ids` have changed since (re-weighting): its hyperparameters describe other costs, and
        measured, starting from them left the fit on a plateau (slope 0.01 instead of 18).
        """
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size < MIN_FIT_POINTS:
            raise CriticInputError(f"the critic needs at least {MIN_FIT_POINTS} observations, has {ids.size}")
        key = self._key(ids) + bytes([local])
        if use_cache and key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        X = self._data.points[ids]
        costs = self._data.costs[ids]
        warm = (
            warm_start is not None
            and warm_start.model.X.shape[1] == X.shape[1]
            and warm_start.compatible_with(ids, self._data.costs)
        )
        model, warm_used = self._fit_vhgp(ids, X, costs, warm_start if warm else None, also_cold)
        with_prior = False
        if self.config.prior is not None:  # the prior's mean where it explains the data better
            model_p, warm_p = self._fit_vhgp(ids, X, self._residuals(X, costs, True), warm_start if warm else None,
                                             also_cold)
            if model_p.bound() > model.bound():
                model, warm_used, with_prior = model_p, warm_p, True
        self.n_fits += 1
        fit = self._local_fit(ids, model, costs, local, with_prior, warm_used)
        self._remember(key, fit)
        return fit

    def _fit_vhgp(self, ids: np.ndarray, X: np.ndarray, y: np.ndarray, warm_start: LocalFit | None,
                  also_cold: bool) -> tuple[VHGP, bool]:
        model = self._new_model(X.shape[1])
        if warm_start is None:
            return model.fit(X, y), False
        model.fit(X, y, warm_start=warm_start.warm_start_for(ids))
        if also_cold:
            cold = self._new_model(X.shape[1]).fit(X, y)
            if cold.bound() > model.bound():
                return cold, False
        return model, True

    def _residuals(self, X: np.ndarray, costs: np.ndarray, with_prior: bool) -> np.ndarray:
        """What the VHGP fits: the costs, or with the prior the costs minus the simulated mean."""
        prior = self.config.prior
        return costs - prior.mean_at(X)[0] if with_prior and prior is not None else costs

    def _local_fit(self, ids: np.ndarray, model: VHGP, costs: np.ndarray, local: bool, with_prior: bool,
                   warm: bool = False) -> LocalFit:
        prior = self.config.prior
        noise = self._noise(model) if local or prior is not None else None
        return LocalFit(ids, model, warm_started=warm, noise=noise, prior=prior if with_prior else None,
                        y=None if prior is None else costs)

    def _noise(self, model: VHGP) -> LogLinearNoise | None:
        """The log-linear noise model of a local fit (None with noise_model "vhgp"); with a
        prior, the one relative to the prior's log variance if its (MAP) likelihood of the
        residuals is higher than that of the model without it."""
        plain = self._log_linear(model, None)
        if plain is None or self.config.prior is None:
            return plain
        offset = self._log_linear(model, self.config.prior)
        return offset if offset is not None and offset.nll < plain.nll else plain

    def _log_linear(self, model: VHGP, prior: CriticPrior | None) -> LogLinearNoise | None:
        if self.config.noise_model != "loglinear":
            return None
        X = np.asarray(model.X)
        e, v = model.loo()
        n, d = X.shape
        extent = np.maximum(X.max(0) - X.min(0), 1e-9 * np.maximum(1.0, np.abs(X).max(0)))
        # d + 1 coefficients from n residuals: the slope prior opens up linearly from n = d + 1
        # to n = 5 (d + 1) points (measured: 10 points in 7-D with the full prior put r~ off
        # by a factor e^11 at the edge of the ball)
        support = min(1.0, max(n - (d + 1), 0) / (4.0 * (d + 1)))
        # below 2 (d + 1) points the residuals cannot separate noise from a mean that can
        # explain any labelling (d + 1 points fit any local linear trend exactly): the level
        # is pooled with 2 (d + 1) - n pseudo-residuals at the neighbourhood's cost variance
        # (measured on the lifting runs: r~ 0.8 where the costs were 4.5 or 38, docs/learner.md)
        y = np.asarray(model.y, dtype=float)
        return fit_log_linear(
            X, e, v, max(support, 1e-3) * (self.config.noise_slope_prior if prior is None
                                           else self.config.prior_slope) / extent,
            spread=float(np.var(y, ddof=1)), pseudo=pseudo_count(n, d) if self.config.small_n_prior else 0,
            prior=prior,
        )

    def _new_model(self, d: int) -> VHGP:
        c = self.config
        ls_min = c.lengthscale_min * math.sqrt(d)
        g_ls_max = max(c.g_lengthscale_max, 2.0 * ls_min)
        g_ls_min = ls_min if c.g_lengthscale_min is None else min(c.g_lengthscale_min, g_ls_max)
        return VHGP(
            fixed_hyperparameters=c.fixed_hyperparameters,
            max_iter=c.cold_iter,
            warm_iter=c.warm_iter,
            lengthscale_range=(ls_min, 50.0),
            g_variance_range=(c.g_variance_min, c.g_variance_max),
            g_lengthscale_range=(g_ls_min, g_ls_max),
        )

    def _remember(self, key: bytes, fit: LocalFit) -> None:
        self._cache[key] = fit
        self._cache.move_to_end(key)
        while len(self._cache) > self.config.cache_size:
            self._cache.popitem(last=False)

    def fit(self, theta: np.ndarray, warm_start: LocalFit | None = None, use_cache: bool = True) -> LocalFit:
        """Fit (or fetch) the VHGP of the neighbourhood of theta (d,)."""
        return self.fit_ids(self.neighbourhood(theta), warm_start=warm_start, use_cache=use_cache)

    def restore(self, record: dict[str, Any]) -> LocalFit:
        """Rebuild a fit from LocalFit.to_dict() without optimising (exact), with the costs
        recorded in it (which may differ from the current ones after re-weighting)."""
        ids = np.asarray(record["ids"], dtype=np.int64)
        if ids.size < MIN_FIT_POINTS or ids.max(initial=-1) >= self._data.points.shape[0] or np.any(np.diff(ids) <= 0):
            raise CriticInputError("fit record refers to observations the critic does not have")
        y = np.asarray(record["y"], dtype=float) if "y" in record else self._data.costs[ids]
        if y.shape != ids.shape:
            raise CriticInputError("fit record: y and ids differ in length")
        X = self._data.points[ids]
        with_prior = bool(record.get("prior_mean", False))
        model = VHGP.from_params(X, self._residuals(X, y, with_prior), VHGPParams.from_dict(record["params"]))
        fit = self._local_fit(ids, model, y, True, with_prior)
        if np.array_equal(y, self._data.costs[ids]):
            self._remember(self._key(ids) + bytes([True]), fit)
        return fit

    def estimate(self, theta: np.ndarray, kappa: float = 0.0, warm_start: LocalFit | None = None) -> CriticEstimate:
        """J~, r~, F~ (and gradients) at theta from the VHGP of theta's neighbourhood."""
        return self.fit(theta, warm_start=warm_start).estimate(theta, kappa)
