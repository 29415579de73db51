"""Episodic Risk-Sensitive Actor-Critic (Kuindersma, Grupen & Barto 2012, Algorithm 1).

Ask/tell loop, one episode per ask:

    ask():   z ~ N(0, diag(sigma^2)) (per-parameter sigma: the natural-gradient variant),
             returns executed = clip(theta + z, bounds).
    tell(executed, J^):
             record (executed, J^); fit the local VHGP critic on the neighbourhood of theta
             (which now includes the new observation);
             z      = executed - theta            (the realised, clipped perturbation)
             delta  = J^ - J~(theta) + kappa (r~(theta + z) - r~(theta))
             alpha  = clip(eta / r~(theta), lr_range)
             theta <- clip(theta - alpha delta z, bounds)

r~ is the critic's predictive noise std sqrt(exp(g_mean + g_var / 2)) (critic/local.py).
Until `min_observations` observations exist (default: the critic's min_neighbours), tell()
only stores the observation (a warm-up Update with step 0).

Batched variant (a fleet of robots evaluating k perturbations in parallel): ask_batch(k)
draws k perturbations around the same theta; tell_batch(executed, costs) records the k
observations in row order and makes one update from the average of their eq. 10 terms,
theta <- clip(theta - alpha mean_i(delta_i z_i), bounds).  k = 1 is exactly ask()/tell().

With a simulator's prior mean in the critic (``CriticConfig.prior``, a kept ``--prior``) the
policy mean moves by ``prior_greedy`` instead (default ``PRIOR_GREEDY``: a model step to the
argmin of F~ within 2 sigma where the critic is confident of the gain; no gradient step);
without one, ``prior_greedy`` changes nothing (docs/learner.md, "Simulator prior").

Pending ask: ask() draws z once; until tell() it returns the same executed parameters (no
new draw).  get_state() includes the pending parameters, so a resumed learner re-issues
exactly the same ask.  tell() must be given those parameters (within 1e-9 of the bounds'
width per coordinate); the learner then uses its own copy, bit for bit.

Resume: get_state() is a JSON-able dict (RNG state, theta, kappa, pending ask, counters,
the last critic fit's VHGP coordinates, a digest of the observations).  ERSAC.from_state()
rebuilds the learner without observations; feed the stored episodes back with observe() in
their original order, then continue; the first tell() checks the digest and continues
with updates bit-identical to an uninterrupted run.

Every public method validates its inputs first and raises a LearnerError subclass without
changing any state.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..critic import CriticConfig, CriticError, CriticEstimate, CriticPrior, FitError, LocalCritic, LocalFit
from ..critic._blas import single_threaded_blas
from .costs import CostWeights, Observations, finite_real
from .errors import (
    InsufficientDataError,
    InvalidInputError,
    InvalidKappaError,
    LearnerError,
    NoPendingAskError,
    PendingAskError,
    OutOfBoundsError,
    PendingMismatchError,
    StateError,
)

#: Default move guard: no update moves a parameter by more than MAX_STEP of its sigma (the
#: whole step is scaled, so its direction is kept). Not in the paper, which bounds the step
#: only through eta / r~ in lr_range; measured (docs/learner.md) it changes ~1-2 % of the
#: updates of the benchmark problems and stops single outlier episodes from throwing theta.
MAX_STEP = 3.0

#: Interleaved search (interleave_every > 0), docs/learner.md: the argmin of F~ is searched
#: within GREEDY_RADIUS sqrt(d) sigma of the fit's observations near theta; the move is taken
#: only if it is at least GREEDY_MIN_MOVE sigma (in some coordinate) and the critic is
#: confident of the gain: F~(argmin) + GREEDY_Z sd(F~(argmin)) < F~(theta).
GREEDY_RADIUS = 1.5
GREEDY_MIN_MOVE = 1.0
GREEDY_Z = 2.0

GREEDY_AROUND = ("data", "theta", "before")


@dataclass(frozen=True)
class GreedyRule:
    """How the interleaved search moves (docs/learner.md "Interleaved offline/online search").

    The argmin of F~ on the update's critic is searched within ``radius`` sqrt(d) sigma of
    ``around``: ``"data"`` the fit's observations within epsilon / 2 of theta (the default),
    ``"theta"`` theta alone (a trust-region step along F~, at most ``radius`` sqrt(d) sigma per
    update), ``"before"`` the policy mean before the update, whose gradient step is then not
    taken (a model step: theta moves only where F~ says so). theta moves there if the move is
    at least ``min_move`` sigma in some coordinate and F~(argmin) + ``z`` sd(F~(argmin)) <
    F~(theta) (``z`` 0: whenever F~ is lower)."""

    z: float = GREEDY_Z
    radius: float = GREEDY_RADIUS
    min_move: float = GREEDY_MIN_MOVE
    around: str = "data"

    def __post_init__(self) -> None:
        for name in ("z", "radius", "min_move"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or v < 0:
                raise InvalidInputError(f"greedy {name} must be finite and >= 0, got {v!r}")
        if self.radius <= 0:
            raise InvalidInputError("greedy radius must be > 0")
        if self.around not in GREEDY_AROUND:
            raise InvalidInputError(f"greedy around must be one of {GREEDY_AROUND}, got {self.around!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> "GreedyRule":
        """The rule of a state (``None``: a state saved before the rule had settings)."""
        return cls() if data is None else cls(**data)


#: How the policy mean moves while the critic has a simulator's prior mean (a kept ``--prior``,
#: docs/learner.md "Simulator prior"): a model step, no gradient step.
PRIOR_GREEDY = GreedyRule(z=1.0, radius=2.0, min_move=0.0, around="before")

STATE_FORMAT = "ersac-hil/ersac-state"
STATE_VERSION = 1


@dataclass(frozen=True, eq=False)
class Update:
    """Result of one tell().  Arrays have shape (d,); executed and z (k, d) after a
    tell_batch(), whose cost, r_tilde_perturbed and td_error are the means over the k rows.

    J_tilde, r_tilde, r_tilde_perturbed, td_error are None for warm-up tells and skipped
    updates (no update).  step_size is alpha = clip(eta / r~(theta), lr_range) (0 in warm-up).
    skipped: why the update was skipped (the critic could not fit; the observation is kept
    and theta unchanged), else None.  step_scale: the factor the move guard applied to the
    step (1.0: unchanged; see ERSAC max_step).  offline: theta_after is the offline argmin of
    F~ on this update's critic (interleaved search), not the gradient step."""

    index: int
    theta_before: np.ndarray
    theta_after: np.ndarray
    executed: np.ndarray
    z: np.ndarray
    cost: float
    J_tilde: float | None
    r_tilde: float | None
    r_tilde_perturbed: float | None
    td_error: float | None
    kappa: float
    step_size: float
    warmup: bool
    clipped: bool
    n_neighbours: int
    skipped: str | None = None
    step_scale: float = 1.0
    offline: bool = False

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = [float(x) for x in v] if isinstance(v, np.ndarray) else v
        return out


def _rng_state_to_json(rng: np.random.Generator) -> dict[str, Any]:
    st = rng.bit_generator.state
    if st.get("bit_generator") != "PCG64":  # pragma: no cover - we only create PCG64
        raise StateError("only PCG64 generators can be saved")
    return {
        "bit_generator": "PCG64",
        "state": str(st["state"]["state"]),
        "inc": str(st["state"]["inc"]),
        "has_uint32": int(st["has_uint32"]),
        "uinteger": int(st["uinteger"]),
    }


def _rng_from_json(data: Mapping[str, Any]) -> np.random.Generator:
    try:
        if data["bit_generator"] != "PCG64":
            raise StateError("rng.bit_generator must be PCG64")
        bg = np.random.PCG64()
        bg.state = {
            "bit_generator": "PCG64",
            "state": {"state": int(data["state"]), "inc": int(data["inc"])},
            "has_uint32": int(data["has_uint32"]),
            "uinteger": int(data["uinteger"]),
        }
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"invalid rng state: {exc}") from exc
    return np.random.Generator(bg)


class ERSAC:
    """ERSAC learner with an ask/tell interface (see module doc)."""

    def __init__(
        self,
        theta0: object,
        sigma: object,
        eta: float,
        kappa: float,
        epsilon: float,
        bounds: object,
        lr_range: tuple[float, float] = (0.01, 0.5),
        seed: int | None = None,
        *,
        weights: CostWeights | None = None,
        critic: CriticConfig | None = None,
        min_observations: int | None = None,
        max_step: float | None = MAX_STEP,
        interleave_every: int = 0,
        greedy: GreedyRule | None = None,
        prior_greedy: GreedyRule | None = PRIOR_GREEDY,
    ) -> None:
        b = np.asarray(bounds, dtype=float)
        if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
            raise InvalidInputError(f"bounds must have shape (d, 2), got {b.shape}")
        if not np.all(np.isfinite(b)) or not np.all(b[:, 0] < b[:, 1]):
            raise InvalidInputError("bounds must be finite with lo < hi")
        d = b.shape[0]
        self._lo, self._hi = b[:, 0].copy(), b[:, 1].copy()
        theta = self._check_params(theta0, "theta0")
        s = np.asarray(sigma, dtype=float)
        if s.ndim == 0:
            s = np.full(d, float(s))
        if s.shape != (d,) or not np.all(np.isfinite(s)) or not np.all(s > 0):
            raise InvalidInputError(f"sigma must be a positive scalar or shape ({d},)")
        self._eta = finite_real(eta, "eta")
        if self._eta <= 0:
            raise InvalidInputError("eta must be > 0")
        lr = (finite_real(lr_range[0], "lr_range[0]"), finite_real(lr_range[1], "lr_range[1]"))
        if not (0 < lr[0] <= lr[1]):
            raise InvalidInputError("lr_range must satisfy 0 < lo <= hi")
        eps = finite_real(epsilon, "epsilon")
        try:
            cfg = CriticConfig(epsilon=eps) if critic is None else dataclasses.replace(critic, epsilon=eps)
        except CriticError as exc:
            raise InvalidInputError(str(exc)) from exc
        if weights is not None and not isinstance(weights, CostWeights):
            raise InvalidInputError("weights must be a CostWeights")
        m = cfg.min_neighbours if min_observations is None else min_observations
        if not isinstance(m, numbers.Integral) or m < 3:
            raise InvalidInputError("min_observations must be an integer >= 3")
        if seed is not None and (not isinstance(seed, numbers.Integral) or seed < 0):
            raise InvalidInputError("seed must be a non-negative integer or None")
        if max_step is not None and (finite_real(max_step, "max_step") <= 0):
            raise InvalidInputError("max_step must be > 0 (in units of sigma) or None")
        if isinstance(interleave_every, bool) or not isinstance(interleave_every, numbers.Integral) or interleave_every < 0:
            raise InvalidInputError("interleave_every must be an integer >= 0 (0: off)")
        if greedy is not None and not isinstance(greedy, GreedyRule):
            raise InvalidInputError("greedy must be a GreedyRule")
        if prior_greedy is not None and not isinstance(prior_greedy, GreedyRule):
            raise InvalidInputError("prior_greedy must be a GreedyRule")

        self._d = d
        self._theta = theta
        self._sigma = s
        self._kappa = finite_real(kappa, "kappa", InvalidKappaError)
        self._lr = lr
        self._min_obs = int(m)
        self._max_step = None if max_step is None else float(max_step)
        self._interleave = int(interleave_every)
        self._greedy = GreedyRule() if greedy is None else greedy
        self._prior_greedy = prior_greedy
        self._skipped: list[tuple[int, str]] = []
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._observations = Observations(d, weights)
        self._critic = LocalCritic(self._observations, cfg)
        self._pending: np.ndarray | None = None
        self._n_updates = 0
        self._last_fit: LocalFit | None = None
        # resume bookkeeping (from_state)
        self._expect_obs = 0
        self._expect_digest: str | None = None
        self._fit_record: dict[str, Any] | None = None

    def set_critic_prior(self, prior: CriticPrior | None) -> None:
        """Give the critic a simulator's prediction as its prior mean (``CriticConfig.prior``,
        the residual model) or take it away (None); every later fit is cold."""
        self._critic = LocalCritic(self._observations, dataclasses.replace(self._critic.config, prior=prior))
        self._last_fit = None
        self._fit_record = None

    # ------------------------------------------------------------------ validation
    def _check_params(self, x: object, what: str) -> np.ndarray:
        xa = np.asarray(x, dtype=float)
        d = self._lo.shape[0]
        if xa.shape != (d,):
            raise InvalidInputError(f"{what} must have shape ({d},), got {xa.shape}")
        if not np.all(np.isfinite(xa)):
            raise InvalidInputError(f"{what} must be finite")
        if np.any(xa < self._lo) or np.any(xa > self._hi):
            raise OutOfBoundsError(f"{what} {xa.tolist()} outside bounds lo={self._lo.tolist()} hi={self._hi.tolist()}")
        return xa.copy()

    # ------------------------------------------------------------------ properties
    @property
    def theta(self) -> np.ndarray:
        """Current policy parameters, (d,) (a copy)."""
        return self._theta.copy()

    @theta.setter
    def theta(self, value: object) -> None:
        """Adopt new policy parameters (an offline selection, an operator's choice).

        Refused (``PendingAskError``) while an ask() awaits its tell(): the pending
        perturbation was drawn around the old theta. Out-of-bounds or non-finite values raise
        and change nothing."""
        theta = self._check_params(value, "theta")
        if self._pending is not None:
            raise PendingAskError("cannot set theta while an ask() awaits its tell(); discard() it first")
        self._theta = theta

    def discard(self) -> None:
        """Forget the pending ask() (its parameters could not be executed). The RNG is not
        rewound: the next ask() draws a new perturbation, deterministically from the seed."""
        self._pending = None

    @property
    def kappa(self) -> float:
        return self._kappa

    @kappa.setter
    def kappa(self, value: float) -> None:
        """Risk sensitivity; takes effect at the next tell()."""
        self._kappa = finite_real(value, "kappa", InvalidKappaError)

    @property
    def dim(self) -> int:
        return self._d

    @property
    def bounds(self) -> np.ndarray:
        return np.column_stack([self._lo, self._hi])

    @property
    def sigma(self) -> np.ndarray:
        return self._sigma.copy()

    @property
    def pending(self) -> np.ndarray | None:
        """Parameters of the ask() awaiting tell(), or None."""
        return None if self._pending is None else self._pending.copy()

    @property
    def n_updates(self) -> int:
        """Number of tell() calls so far (warm-up tells included)."""
        return self._n_updates

    @property
    def min_observations(self) -> int:
        """Observations before the first update (warm-up tells only store them)."""
        return self._min_obs

    @property
    def n_observations(self) -> int:
        return len(self._observations)

    @property
    def skipped_updates(self) -> list[tuple[int, str]]:
        """(update index, reason) of every update skipped because the critic could not fit."""
        return list(self._skipped)

    @property
    def observations(self) -> Observations:
        """The observations (read-only views; add through observe/tell)."""
        return self._observations

    @property
    def weights(self) -> CostWeights:
        return self._observations.weights

    @property
    def greedy(self) -> GreedyRule:
        """The interleaved search's move rule (used when ``interleave_every`` > 0)."""
        return self._greedy

    @property
    def local_critic(self) -> LocalCritic:
        return self._critic

    # ------------------------------------------------------------------ ask / tell
    def ask(self) -> np.ndarray:
        """Parameters to execute next: clip(theta + z, bounds), (d,).  Idempotent until tell()."""
        if self._pending is not None and self._pending.ndim == 2:
            raise PendingAskError("a batch from ask_batch() awaits its tell_batch()")
        if self._pending is None:
            z = self._rng.standard_normal(self._d) * self._sigma
            self._pending = np.clip(self._theta + z, self._lo, self._hi)
        return self._pending.copy()

    def _check_executed(self, executed: object) -> np.ndarray:
        if self._pending is None or self._pending.ndim != 1:
            raise NoPendingAskError("tell() without a pending ask()")
        x = self._check_params(executed, "executed")
        tol = 1e-9 * (self._hi - self._lo)
        if np.any(np.abs(x - self._pending) > tol):
            raise PendingMismatchError(f"executed {x.tolist()} differs from the pending ask {self._pending.tolist()}")
        return self._pending.copy()

    def _check_resume(self) -> None:
        n = len(self._observations)
        if n < self._expect_obs:
            raise StateError(f"resume incomplete: state was saved with {self._expect_obs} observations, {n} observed so far")
        if self._expect_digest is not None:
            if self._digest(self._expect_obs) != self._expect_digest:
                raise StateError("the observed episodes differ from those the state was saved with")
            self._expect_digest = None
        if self._fit_record is not None:
            try:
                self._last_fit = self._critic.restore(self._fit_record)
            except (CriticError, KeyError, TypeError, ValueError):
                # a record that cannot be rebuilt only costs the warm start: the next
                # update fits cold (the run stays resumable)
                self._last_fit = None
            self._fit_record = None

    def tell(self, executed: object, cost: Mapping[str, float] | float) -> Update:
        """Report the cost of the pending ask and update theta (see module doc).

        cost: a number (single-term weights) or a mapping term name -> value."""
        x = self._check_executed(executed)
        return self._tell(x[None, :], [cost], batched=False)

    def _tell(self, X: np.ndarray, costs: list[Mapping[str, float] | float], batched: bool) -> Update:
        """Record the k rows of X (k, d) with their costs, then one update (see module doc)."""
        for x, cost in zip(X, costs):
            self._observations.prepare(x, cost)  # validates every cost before any change
        self._check_resume()
        theta = self._theta.copy()
        Z = X - theta
        first = len(self._observations)
        for x, cost in zip(X, costs):
            self._observations.add(x, cost)
        J_hat = np.array(self._observations.costs[first:], dtype=float)
        row = (lambda a: a.mean(axis=0)) if batched else (lambda a: a[0])  # noqa: E731
        try:
            if len(self._observations) < self._min_obs:
                upd = Update(
                    self._n_updates, theta, theta.copy(), X if batched else X[0], Z if batched else Z[0],
                    float(row(J_hat)), None, None, None, None, self._kappa, 0.0, True, False, 0,
                )
                new_theta, fit = theta, self._last_fit
            else:
                upd, new_theta, fit = self._update(theta, X, Z, J_hat, batched)
        except BaseException:
            self._observations.truncate(first)
            raise
        self._theta = new_theta
        self._last_fit = fit
        if upd.skipped is not None:
            self._skipped.append((upd.index, upd.skipped))
        self._pending = None
        self._n_updates += 1
        return upd

    # ------------------------------------------------------------------ batched ask / tell
    def ask_batch(self, k: int) -> np.ndarray:
        """k perturbations around the same theta for one batched update, (k, d): row i is
        clip(theta + z_i, bounds).  The rows are drawn in order from the same random stream
        as ask(), so ask_batch(1)[0] == ask().  Idempotent until tell_batch()."""
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1:
            raise InvalidInputError(f"k must be an integer >= 1, got {k!r}")
        if self._pending is not None and self._pending.shape != (k, self._d):
            raise PendingAskError(f"a pending ask of shape {self._pending.shape} awaits its tell")
        if self._pending is None:
            Z = self._rng.standard_normal((int(k), self._d)) * self._sigma
            self._pending = np.clip(self._theta + Z, self._lo, self._hi)
        return self._pending.copy()

    def reask(self, i: int) -> np.ndarray:
        """A new draw for row i of the pending batch (its parameters could not be executed);
        the other rows stay.  Returns the new row, (d,)."""
        if self._pending is None or self._pending.ndim != 2:
            raise NoPendingAskError("reask() without a pending ask_batch()")
        if isinstance(i, bool) or not isinstance(i, numbers.Integral) or not 0 <= i < len(self._pending):
            raise InvalidInputError(f"row {i!r} not in the pending batch of {len(self._pending)}")
        z = self._rng.standard_normal(self._d) * self._sigma
        self._pending[i] = np.clip(self._theta + z, self._lo, self._hi)
        return self._pending[i].copy()

    def tell_batch(self, executed: object, costs: list[Mapping[str, float] | float]) -> Update:
        """Report the costs of the pending batch (executed (k, d), k costs in row order) and
        make one update from the average of the rows' eq. 10 terms:
        theta <- clip(theta - alpha mean_i(delta_i z_i), bounds), with
        delta_i = J^_i - J~(theta) + kappa (r~(theta + z_i) - r~(theta)) and alpha from
        r~(theta) as in tell().  The k observations are recorded in row order.  The Update's
        executed and z have shape (k, d); cost, r_tilde_perturbed and td_error are the rows'
        means.  k = 1 gives the same theta, critic values and state as ask()/tell()."""
        if self._pending is None or self._pending.ndim != 2:
            raise NoPendingAskError("tell_batch() without a pending ask_batch()")
        X = np.asarray(executed, dtype=float)
        if X.shape != self._pending.shape:
            raise InvalidInputError(f"executed must have shape {self._pending.shape}, got {X.shape}")
        if not isinstance(costs, (list, tuple)) or len(costs) != len(X):
            raise InvalidInputError(f"costs must be a list of {len(X)} costs")
        for i, x in enumerate(X):
            self._check_params(x, f"executed[{i}]")
        tol = 1e-9 * (self._hi - self._lo)
        if np.any(np.abs(X - self._pending) > tol):
            raise PendingMismatchError(f"executed {X.tolist()} differs from the pending batch {self._pending.tolist()}")
        return self._tell(self._pending.copy(), list(costs), batched=True)

    def _update_fit(self, theta: np.ndarray) -> LocalFit:
        ids = self._critic.neighbourhood(theta)
        last = self._last_fit
        if last is not None and np.array_equal(last.ids, ids) and np.array_equal(last.costs, self._observations.costs[ids]):
            return last
        every = self._critic.config.cold_every
        also_cold = every > 0 and self._n_updates % every == 0
        return self._critic.fit_ids(ids, warm_start=last, use_cache=False, also_cold=also_cold)

    def _update(self, theta: np.ndarray, X: np.ndarray, Z: np.ndarray, J_hat: np.ndarray,
                batched: bool) -> tuple[Update, np.ndarray, LocalFit | None]:
        """One update from the k rows X, Z (k, d) and costs J_hat (k,)."""
        kappa = self._kappa
        row = (lambda a: a.mean(axis=0)) if batched else (lambda a: a[0])  # noqa: E731
        executed, z = (X, Z) if batched else (X[0], Z[0])
        with single_threaded_blas():
            try:
                fit = self._update_fit(theta)
                J_t, r_t, _ = (float(v[0]) for v in fit.estimate_many(theta[None, :]))
                if self._critic.config.clip_mean:  # the TD baseline within its costs' range
                    J_t = float(np.clip(J_t, np.min(fit.costs), np.max(fit.costs)))
                r_p = np.asarray(fit.estimate_many(X)[1], dtype=float)
                if not (math.isfinite(J_t) and math.isfinite(r_t) and np.all(np.isfinite(r_p))) or r_t <= 0:
                    raise FitError(f"non-finite critic values J~ {J_t}, r~ {r_t}, r~(theta+z) {r_p.tolist()}")
            except CriticError as exc:
                # the observations are kept; theta and the fit chain stay as they were
                reason = f"critic fit failed: {exc}"
                upd = Update(
                    self._n_updates, theta, theta.copy(), executed, z, float(row(J_hat)), None, None, None,
                    None, kappa, 0.0, False, False, 0, skipped=reason,
                )
                return upd, theta, self._last_fit
        deltas = J_hat - J_t + kappa * (r_p - r_t)
        alpha = float(np.clip(self._eta / r_t, self._lr[0], self._lr[1]))
        step = row(-alpha * deltas[:, None] * Z)  # k = 1: exactly -alpha * delta * z
        scale = 1.0
        if self._max_step is not None:
            largest = float(np.max(np.abs(step) / self._sigma))
            if largest > self._max_step:
                scale = self._max_step / largest
        raw = theta + scale * step
        new_theta = np.clip(raw, self._lo, self._hi)
        clipped = bool(np.any(raw != new_theta))
        offline = False
        if self._prior_greedy is not None and self._critic.config.prior is not None:
            new_theta, offline = self._greedy_move(fit, new_theta, kappa, self._prior_greedy, theta)
        elif self._interleave > 0 and (self._n_updates + 1) % self._interleave == 0:
            new_theta, offline = self._greedy_move(fit, new_theta, kappa)
        upd = Update(
            self._n_updates, theta, new_theta.copy(), executed, z, float(row(J_hat)), J_t, r_t,
            float(row(r_p)), float(row(deltas)), kappa, alpha, False, clipped, int(fit.ids.size),
            step_scale=scale, offline=offline,
        )
        return upd, new_theta, fit

    def _greedy_move(self, fit: LocalFit, theta: np.ndarray, kappa: float, rule: GreedyRule | None = None,
                     before: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
        """Interleaved search: theta, or the argmin of F~ of this update's critic near theta
        if the critic is confident of the gain there (see ERSAC's module doc)."""
        X = np.asarray(fit.model.X)
        d, rule = self._d, (self._greedy if rule is None else rule)
        if rule.around == "before" and before is not None:
            theta = before
        if rule.around in ("theta", "before"):
            region = theta[None, :]
        else:
            region = X[np.linalg.norm(X - theta, axis=1) <= 0.5 * self._critic.config.epsilon]
        if region.shape[0] == 0:
            return theta, False
        cfg = SelectionConfig(radius=rule.radius * math.sqrt(d) * float(self._sigma.min()))
        with single_threaded_blas():
            sel = minimise_on_fit(fit, self.bounds, kappa, theta, cfg, region=region)
            here = fit.estimate(theta, kappa)
            there = fit.estimate(sel.theta, kappa)
        # moves below a sigma are left to the gradient steps; confident: sd(F~) from the
        # posterior of J~ and of g (var r~ ~ r~^2 var(g) / 4), measured in docs/learner.md
        travels = float(np.max(np.abs(sel.theta - theta) / self._sigma)) >= rule.min_move
        sd = math.sqrt(max(there.J_var, 0.0) + kappa**2 * there.r**2 * there.g_var / 4.0)
        if travels and there.F + rule.z * sd < here.F:
            return sel.theta.copy(), True
        return theta, False

    def observe(self, executed: object, cost: Mapping[str, float] | float) -> int:
        """Add a past observation without an update (rebuilding the critic); returns its index."""
        x = self._check_params(executed, "executed")
        return self._observations.add(x, cost)

    def reweight(self, weights: CostWeights) -> None:
        """New cost weights: every stored cost is recomputed from its terms. A critic prior
        (a simulator's costs under the weights it was made with) is dropped when the weights
        change."""
        before = self._observations.weights
        self._observations.reweight(weights)
        if self._critic.config.prior is not None and self._observations.weights.to_dict() != before.to_dict():
            self.set_critic_prior(None)

    @property
    def critic_prior(self) -> CriticPrior | None:
        """The critic's prior mean (``CriticConfig.prior``), if any."""
        return self._critic.config.prior

    # ------------------------------------------------------------------ critic queries
    def critic_estimate(self, theta: object, kappa: float | None = None) -> CriticEstimate:
        """J~, r~, F~ and gradients at theta (d,) from its neighbourhood's VHGP."""
        th = self._check_params(theta, "theta")
        k = self._kappa if kappa is None else finite_real(kappa, "kappa", InvalidKappaError)
        if len(self._observations) < 3:
            raise InsufficientDataError(f"the critic needs at least 3 observations, has {len(self._observations)}")
        self._check_resume()
        with single_threaded_blas():
            try:
                return self._critic.fit(th, warm_start=self._last_fit).estimate(th, k)
            except CriticError as exc:
                raise InsufficientDataError(f"critic fit failed: {exc}") from exc

    def critic(self, theta: object) -> tuple[float, float]:
        """(J~(theta), r~(theta))."""
        e = self.critic_estimate(theta)
        return e.J, e.r

    def select(self, kappa: float | None = None, **options: Any) -> "Selection":
        """Offline policy selection for kappa (default: the current kappa); no episodes.
        options: fields of SelectionConfig (radius, n_starts, max_points, ...)."""
        k = self._kappa if kappa is None else finite_real(kappa, "kappa", InvalidKappaError)
        self._check_resume()
        if "radius" not in options:
            options["radius"] = 0.5 * self._critic.config.epsilon
        try:
            cfg = SelectionConfig(**options)
        except TypeError as exc:
            raise InvalidInputError(str(exc)) from exc
        return select_policy(self._critic, self.bounds, k, anchor=self._theta, config=cfg, warm_start=self._last_fit)

    # ------------------------------------------------------------------ state
    def _digest(self, n: int) -> str:
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self._observations.points[:n]).tobytes())
        h.update(np.ascontiguousarray(self._observations.terms[:n]).tobytes())
        return h.hexdigest()

    def get_state(self) -> dict[str, Any]:
        """JSON-able snapshot (plain dicts, lists, str, int, float, None); observations
        themselves are not included (see module doc)."""
        fit = self._last_fit.to_dict() if self._last_fit is not None else self._fit_record
        return {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "theta": [float(v) for v in self._theta],
            "sigma": [float(v) for v in self._sigma],
            "bounds": [[float(a), float(b)] for a, b in zip(self._lo, self._hi)],
            "eta": self._eta,
            "kappa": self._kappa,
            "lr_range": [self._lr[0], self._lr[1]],
            "min_observations": self._min_obs,
            "max_step": self._max_step,
            "interleave_every": self._interleave,
            "greedy": self._greedy.to_dict(),
            # only with a critic prior (the rule acts only then): other states stay as they were
            **({} if self._critic.config.prior is None else
               {"prior_greedy": None if self._prior_greedy is None else self._prior_greedy.to_dict()}),
            "critic": self._critic.config.to_dict(),
            "weights": self._observations.weights.to_dict(),
            "rng": _rng_state_to_json(self._rng),
            "pending": None if self._pending is None else self._pending.tolist(),
            "n_updates": self._n_updates,
            "n_observations": max(len(self._observations), self._expect_obs),
            "observations_sha256": self._digest(len(self._observations)) if len(self._observations) >= self._expect_obs else self._expect_digest,
            "last_fit": fit,
            "skipped_updates": [[i, reason] for i, reason in self._skipped],
        }

    @staticmethod
    def _prior_rule(state: Mapping[str, Any], critic: CriticConfig) -> GreedyRule | None:
        """The prior rule of a state: its own; a state with a critic prior but no rule was
        saved before the rule existed (the preset's steps then, as it was made); else the
        default."""
        if "prior_greedy" in state:
            return None if state["prior_greedy"] is None else GreedyRule.from_dict(state["prior_greedy"])
        return None if critic.prior is not None else PRIOR_GREEDY

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "ERSAC":
        """Rebuild a learner from get_state(); then observe() the stored episodes in order."""
        try:
            if state.get("format") != STATE_FORMAT or state.get("version") != STATE_VERSION:
                raise StateError(f"not an {STATE_FORMAT} v{STATE_VERSION} state")
            critic = CriticConfig.from_dict(state["critic"])
            learner = cls(
                state["theta"],
                state["sigma"],
                state["eta"],
                state["kappa"],
                critic.epsilon,
                state["bounds"],
                lr_range=tuple(state["lr_range"]),
                weights=CostWeights(state["weights"]),
                critic=critic,
                min_observations=state["min_observations"],
                max_step=state.get("max_step", MAX_STEP),
                interleave_every=state.get("interleave_every", 0),
                greedy=GreedyRule.from_dict(state.get("greedy")),
                prior_greedy=cls._prior_rule(state, critic),
            )
            learner._rng = _rng_from_json(state["rng"])
            if state["pending"] is not None:
                pending = np.asarray(state["pending"], dtype=float)
                learner._pending = (np.array([learner._check_params(x, "pending") for x in pending])
                                    if pending.ndim == 2 else learner._check_params(pending, "pending"))
            learner._n_updates = int(state["n_updates"])
            learner._expect_obs = int(state["n_observations"])
            learner._expect_digest = state["observations_sha256"]
            learner._fit_record = state["last_fit"]
            learner._skipped = [(int(i), str(reason)) for i, reason in state.get("skipped_updates", [])]
        except StateError:
            raise
        except (LearnerError, CriticError, KeyError, TypeError, ValueError) as exc:
            raise StateError(f"invalid learner state: {exc}") from exc
        return learner


from .selection import Selection, SelectionConfig, minimise_on_fit, select_policy  # noqa: E402  (avoids an import cycle)
