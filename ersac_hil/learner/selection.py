"""Offline policy selection: argmin F~(theta, kappa) = J~ + kappa r~ over the data's region.

No new episodes.  One VHGP is fitted to the `max_points` observations nearest to the anchor
(the learner's theta; all observations if there are fewer).  The search is restricted to
the region the data supports, the trust region

    T = { theta in bounds : min_i ||theta - x_i|| <= radius },  x_i the model's observations,

expressed as the NLopt inequality constraint min_i ||theta - x_i||^2 - radius^2 <= 0
(gradient 2 (theta - x_nearest), nearest point from a KD-tree).  NLopt SLSQP with the
analytic gradient of F~ runs from the `n_starts` observed points with the lowest F~ (points
closer than radius / 2 to an already chosen start are skipped), and the best feasible
point found wins (the starts themselves are candidates, so the result is never worse than
the best observed point under the model).

Two cost modes (``low_mode``).  The VHGP models a cost whose mean and noise vary smoothly
with theta.  A cost that jumps between two well-separated levels as a deterministic function
of theta (a lift that fails, h_error_sq ~730, against one that succeeds; test trials of one
policy differ by ~0.01, the two levels by ~30) is outside that model: fitted on both, the
noise process absorbs the jump (measured: r~ 15-17 everywhere, J~ 22.7 where the observed
cost is 5.88), F~ carries no local information and the selection lands anywhere.  When the
model's costs split into two modes, the selection model is fitted to the low mode only, and
the failure side is kept out of the search:

- modes: on the log of the costs (positive integrals; the log makes each mode's spread
  relative to its level), the split between consecutive sorted values with the largest gap
  over the sum of the two groups' standard deviations, if that ratio exceeds
  ``MODE_SEPARATION``, with at least ``MODE_MIN_POINTS`` in each group and
  ``MODE_MIN_DATA`` in all;
- theta stays at least as near to an observation of the low mode as to one of the high mode
  (its nearest observation is a success): min_i ||theta - x_i||^2 - min_j ||theta - f_j||^2
  <= 0;
- the trust radius is ``MODE_RADIUS`` x radius around the low mode's observations: the cliff
  between the modes is not in the data, and the model extrapolates the low mode across it.
  Measured on 5 learned lifting runs x 2 risk contexts (test trials): at the full radius
  (0.13) 2 of 10 selections crossed into failure, at 1/2 1 of 10, at 0.02 none, and all 10
  lowered the re-weighted cost.

On one-mode data nothing changes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import nlopt
import numpy as np
from scipy.spatial import cKDTree

from ..critic import CriticError, LocalCritic, LocalFit
from ..critic._blas import single_threaded_blas
from .errors import InsufficientDataError, InvalidInputError

#: Separation (gap of the log costs over the sum of the two groups' standard deviations) from
#: which the costs are two modes.  Measured, 0.1 % quantile of the largest ratio of one-mode
#: samples of 20-150 costs: normal, log-normal, exponential, uniform <= 2.7, Pareto(3) <= 3.0;
#: the 30 episodes of each of 5 learned lifting runs, under the default and both context
#: weights: 3.7-14.7.
MODE_SEPARATION = 3.0
#: Fewest observations in each mode (one or two outliers are left to the noise model).
MODE_MIN_POINTS = 3
#: Fewest observations for a split (below 20, one-mode samples reach ratios of 5-18).
MODE_MIN_DATA = 20
#: Trust radius around the low mode's observations, as a fraction of the configured radius.
MODE_RADIUS = 0.125

_RESULT_NAMES = {
    nlopt.SUCCESS: "success",
    nlopt.STOPVAL_REACHED: "stopval_reached",
    nlopt.FTOL_REACHED: "ftol_reached",
    nlopt.XTOL_REACHED: "xtol_reached",
    nlopt.MAXEVAL_REACHED: "maxeval_reached",
    nlopt.MAXTIME_REACHED: "maxtime_reached",
}


@dataclass(frozen=True)
class SelectionConfig:
    """radius: trust-region radius (parameter units); n_starts; max_points: observations in
    the selection model; max_eval: SLSQP evaluations per start; xtol_rel, ftol_abs: SLSQP
    stopping tolerances."""

    radius: float
    #: > 0: among the SLSQP result, the anchor and the region's observed points the one of
    #: lowest F~ + pessimism sd(F~) wins, sd^2 = var(J~) + kappa^2 r~^2 var(g) / 4 (the
    #: model's own uncertainty; docs/learner.md "The default learner"); 0: argmin of F~.
    pessimism: float = 0.0
    n_starts: int = 5
    max_points: int = 150
    max_eval: int = 100
    xtol_rel: float = 1e-6
    ftol_abs: float = 1e-9

    def __post_init__(self) -> None:
        if not (isinstance(self.radius, (int, float)) and math.isfinite(self.radius) and self.radius > 0):
            raise InvalidInputError("radius must be finite and > 0")
        if not (isinstance(self.pessimism, (int, float)) and math.isfinite(self.pessimism) and self.pessimism >= 0):
            raise InvalidInputError("pessimism must be finite and >= 0")
        if self.n_starts < 1 or self.max_points < 3 or self.max_eval < 1:
            raise InvalidInputError("n_starts >= 1, max_points >= 3 and max_eval >= 1 required")


@dataclass(frozen=True, eq=False)
class Selection:
    """The selected policy theta (d,) with the model's J~, r~, F~ = J~ + kappa r~ there."""

    theta: np.ndarray
    J_tilde: float
    r_tilde: float
    F_tilde: float
    kappa: float
    distance_to_data: float
    radius: float
    start: np.ndarray
    n_points: int
    n_starts: int
    n_evaluations: int
    status: str
    n_excluded: int = 0


def low_mode(costs: np.ndarray, separation: float = MODE_SEPARATION, min_points: int = MODE_MIN_POINTS,
             min_data: int = MODE_MIN_DATA) -> np.ndarray | None:
    """Mask (n,) of the low-cost group when the costs (n,) split into two modes (module doc),
    else None (also for fewer than ``min_data`` costs or any cost <= 0)."""
    y = np.asarray(costs, dtype=float).reshape(-1)
    n = y.size
    if n < max(min_data, 2 * min_points) or not np.all(y > 0):
        return None
    raw = np.sort(y)
    s = np.log(raw)
    tiny = 1e-12 * max(1.0, float(np.abs(s).max()))
    best_k, best = -1, 0.0
    for k in range(min_points - 1, n - min_points):
        score = (s[k + 1] - s[k]) / (s[: k + 1].std() + s[k + 1 :].std() + tiny)
        if score > best:
            best_k, best = k, score
    if best_k < 0 or best <= separation:
        return None
    return y <= raw[best_k]


def select_policy(
    critic: LocalCritic,
    bounds: np.ndarray,
    kappa: float,
    anchor: np.ndarray,
    config: SelectionConfig,
    warm_start: LocalFit | None = None,
) -> Selection:
    """Minimise F~ in the trust region (module doc).  bounds (d, 2), anchor (d,)."""
    pts = critic.data.points
    N, d = pts.shape
    if N < 3:
        raise InsufficientDataError(f"selection needs at least 3 observations, has {N}")
    with single_threaded_blas():
        if N <= config.max_points:
            ids = np.arange(N, dtype=np.int64)
        else:
            ids = critic.nearest(anchor, config.max_points)
        region = avoid = None
        low = low_mode(critic.data.costs[ids])
        if low is not None:
            region, avoid = pts[ids[low]], pts[ids[~low]]
            ids = ids[low]
            config = dataclasses.replace(config, radius=MODE_RADIUS * config.radius)
        try:
            fit = critic.fit_ids(ids, warm_start=warm_start, local=False)
        except CriticError as exc:
            raise InsufficientDataError(f"selection model fit failed: {exc}") from exc
        return minimise_on_fit(fit, bounds, kappa, anchor, config, region=region, avoid=avoid)


def _least_pessimistic(fit: LocalFit, kappa: float, z: float, best: tuple, Xd: np.ndarray,
                       feasible) -> tuple:  # noqa: ANN001
    """Among ``best`` (the SLSQP result) and the feasible observed points ``Xd``, the one of
    lowest F~ + z sd(F~) (SelectionConfig.pessimism)."""
    cands = [best[1]] + [x for x in Xd if feasible(x)]
    scores = []
    for x in cands:
        e = fit.estimate(x, kappa)
        scores.append(e.F + z * math.sqrt(max(e.J_var, 0.0) + kappa**2 * e.r**2 * max(e.g_var, 0.0) / 4.0))
    i = int(np.argmin(scores))
    return best if i == 0 else (float(fit.estimate(cands[i], kappa).F), np.asarray(cands[i]).copy(), best[2], "pessimistic")


def minimise_on_fit(
    fit: LocalFit, bounds: np.ndarray, kappa: float, anchor: np.ndarray, config: SelectionConfig,
    region: np.ndarray | None = None, avoid: np.ndarray | None = None,
) -> Selection:
    """argmin of F~ of `fit` within `config.radius` of the fit's observations (or of the
    points `region` (k, d)), no nearer to any of the points `avoid` (m, d) than to the
    region (module doc: two cost modes), and inside bounds (d, 2); SLSQP from the `n_starts`
    of the region's points of lowest F~.  anchor (d,) is a candidate too if it is feasible
    (so the result is never worse than it under the model)."""
    lo, hi = bounds[:, 0], bounds[:, 1]
    d = bounds.shape[0]
    with single_threaded_blas():
        Xd = np.asarray(fit.model.X) if region is None else np.asarray(region, dtype=float)
        tree = cKDTree(Xd)
        R2 = config.radius**2
        _, _, Fd = fit.estimate_many(Xd, kappa)
        starts: list[np.ndarray] = []
        for i in np.argsort(Fd, kind="stable"):
            x = np.clip(Xd[i], lo, hi)
            if all(np.linalg.norm(x - s) >= 0.5 * config.radius for s in starts):
                starts.append(x)
            if len(starts) == config.n_starts:
                break

        n_eval = 0
        best: tuple[float, np.ndarray, np.ndarray, str] | None = None

        def dist2(x: np.ndarray) -> tuple[float, np.ndarray]:
            _, j = tree.query(x)
            diff = x - Xd[j]
            return float(diff @ diff), diff

        Xa = None if avoid is None or len(avoid) == 0 else np.asarray(avoid, dtype=float)
        tree_a = None if Xa is None else cKDTree(Xa)

        def side(x: np.ndarray) -> tuple[float, np.ndarray]:
            """d_region(x)^2 - d_avoid(x)^2 (<= 0: the region's side) and its gradient."""
            v, diff = dist2(x)
            if tree_a is None or Xa is None:
                return -math.inf, np.zeros_like(x)
            _, j = tree_a.query(x)
            diff_a = x - Xa[j]
            return v - float(diff_a @ diff_a), 2.0 * (diff - diff_a)

        def feasible(x: np.ndarray) -> bool:
            return (dist2(x)[0] <= R2 * (1 + 1e-9) and side(x)[0] <= 1e-12
                    and bool(np.all(x >= lo)) and bool(np.all(x <= hi)))

        a = np.clip(np.asarray(anchor, dtype=float), lo, hi)
        if feasible(a):
            best = (float(fit.estimate_many(a[None, :], kappa)[2][0]), a.copy(), a.copy(), "anchor")

        for s in starts:
            track: dict[str, object] = {"F": math.inf, "x": s.copy()}

            def objective(x: np.ndarray, grad: np.ndarray) -> float:
                nonlocal n_eval
                n_eval += 1
                e = fit.estimate(x, kappa)
                if grad.size > 0:
                    grad[:] = e.grad_F
                if e.F < track["F"] and feasible(x):
                    track["F"], track["x"] = e.F, x.copy()
                return float(e.F)

            def constraint(x: np.ndarray, grad: np.ndarray) -> float:
                v, diff = dist2(x)
                if grad.size > 0:
                    grad[:] = 2.0 * diff
                return v - R2

            opt = nlopt.opt(nlopt.LD_SLSQP, d)
            opt.set_lower_bounds(lo.tolist())
            opt.set_upper_bounds(hi.tolist())
            opt.set_min_objective(objective)
            opt.add_inequality_constraint(constraint, 1e-10)
            if tree_a is not None:
                def modes(x: np.ndarray, grad: np.ndarray) -> float:
                    v, g = side(x)
                    if grad.size > 0:
                        grad[:] = g
                    return v

                opt.add_inequality_constraint(modes, 1e-12)
            opt.set_xtol_rel(config.xtol_rel)
            opt.set_ftol_abs(config.ftol_abs)
            opt.set_maxeval(config.max_eval)
            try:
                opt.optimize(s.copy())
                status = _RESULT_NAMES.get(opt.last_optimize_result(), str(opt.last_optimize_result()))
            except (nlopt.RoundoffLimited, nlopt.ForcedStop, ValueError, RuntimeError) as exc:
                status = f"stopped: {type(exc).__name__}"
            F_s = float(track["F"])  # type: ignore[arg-type]
            x_s = track["x"]
            assert isinstance(x_s, np.ndarray)
            if best is None or F_s < best[0]:
                best = (F_s, x_s, s, status)

        assert best is not None
        if config.pessimism > 0:
            best = _least_pessimistic(fit, kappa, config.pessimism, best, Xd, feasible)
        theta = best[1]
        e = fit.estimate(theta, kappa)
    return Selection(
        theta=theta,
        J_tilde=e.J,
        r_tilde=e.r,
        F_tilde=e.F,
        kappa=float(kappa),
        distance_to_data=math.sqrt(dist2(theta)[0]),
        radius=config.radius,
        start=best[2],
        n_points=int(Xd.shape[0]),
        n_starts=len(starts),
        n_evaluations=n_eval,
        status=best[3],
        n_excluded=0 if Xa is None else int(Xa.shape[0]),
    )
