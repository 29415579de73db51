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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import nlopt
import numpy as np
from scipy.spatial import cKDTree

from ..critic import CriticError, LocalCritic, LocalFit
from ..critic._blas import single_threaded_blas
from .errors import InsufficientDataError, InvalidInputError

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
    n_starts: int = 5
    max_points: int = 150
    max_eval: int = 100
    xtol_rel: float = 1e-6
    ftol_abs: float = 1e-9

    def __post_init__(self) -> None:
        if not (isinstance(self.radius, (int, float)) and math.isfinite(self.radius) and self.radius > 0):
            raise InvalidInputError("radius must be finite and > 0")
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
        try:
            fit = critic.fit_ids(ids, warm_start=warm_start, local=False)
        except CriticError as exc:
            raise InsufficientDataError(f"selection model fit failed: {exc}") from exc
        return minimise_on_fit(fit, bounds, kappa, anchor, config)


def minimise_on_fit(
    fit: LocalFit, bounds: np.ndarray, kappa: float, anchor: np.ndarray, config: SelectionConfig,
    region: np.ndarray | None = None,
) -> Selection:
    """argmin of F~ of `fit` within `config.radius` of the fit's observations (or of the
    points `region` (k, d)) and inside bounds (d, 2); SLSQP from the `n_starts` of those
    points of lowest F~ (module doc).  anchor (d,) is a candidate too (so the result is
    never worse than it under the model)."""
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

        a = np.clip(np.asarray(anchor, dtype=float), lo, hi)
        if dist2(a)[0] <= R2:
            best = (float(fit.estimate_many(a[None, :], kappa)[2][0]), a.copy(), a.copy(), "anchor")

        for s in starts:
            track: dict[str, object] = {"F": math.inf, "x": s.copy()}

            def objective(x: np.ndarray, grad: np.ndarray) -> float:
                nonlocal n_eval
                n_eval += 1
                e = fit.estimate(x, kappa)
                if grad.size > 0:
                    grad[:] = e.grad_F
                if e.F < track["F"] and dist2(x)[0] <= R2 * (1 + 1e-9) and np.all(x >= lo) and np.all(x <= hi):
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
    )
