"""The learner of one run: ``ersac_hil.learner.ERSAC`` plus the task's cost terms.

The daemon's only door to the numerical core. Not thread-safe: the daemon holds its lock.
Vectors are tuples of shape ``(dim,)``; cost terms are mappings of the task's term names.

Resume (:meth:`Engine.restore`): ``ERSAC.from_state`` with the state stored after the last
update (RNG, theta, kappa, last critic fit, observation digest), then every stored ok
episode re-observed in order; the latest kappa and weights are applied and a theta adopted
after the last update replaces the stored one. The next ``propose`` then draws exactly the
perturbations an uninterrupted learner would have drawn.

Batches: ``propose(k)`` draws k perturbations around the policy mean (the learner's
``ask_batch``), ``learn`` tells their cost terms together (``tell_batch``: one update from the
average of their eq. 10 terms). k = 1 is the paper's Algorithm 1, bit for bit the learner's
``ask``/``tell``.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ersac_hil.learner import ERSAC, CostWeights, InsufficientDataError
from ersac_hil.learner.presets import LEGACY_LEARNER, preset
from protocol.zenoh import damaged, get_task

from .store import UpdateRecord

__all__ = ["Engine", "Proposal", "NotEnoughData", "MAX_WEIGHT"]

#: Largest accepted cost weight. The task's default weights are 1e-3..10; a risk context
#: raises one by a few orders of magnitude at most. Far larger weights only make the costs
#: overflow the critic's arithmetic (``body_acc_sq=1e300`` once crashed every update).
MAX_WEIGHT = 1e6


class NotEnoughData(RuntimeError):
    """The critic or the selection needs more ok episodes."""


@dataclass(frozen=True)
class Proposal:
    """One ask: policy mean ``base_theta``, realised perturbation ``z`` (after keeping the
    executed parameters in bounds) and executed ``theta = base_theta + z``."""

    base_theta: tuple[float, ...]
    z: tuple[float, ...]
    theta: tuple[float, ...]


def _tuple(a: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(a, dtype=float).reshape(-1))


class Engine:
    """ERSAC for one task. Build with :meth:`create` or :meth:`restore`."""

    def __init__(self, task: str, learner: ERSAC) -> None:
        self.task = task
        self.spec = get_task(task)
        self._learner = learner
        #: why the last :meth:`learn` took no step although past warm-up (the critic could
        #: not fit; the episode is kept and the run goes on), else ``None``
        self.last_skipped: str | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(cls, task: str, settings: Mapping[str, Any]) -> Engine:
        """A fresh learner from the run's stored settings (theta0, sigma, eta, kappa, epsilon,
        lr_range, weights, seed)."""
        spec = get_task(task)
        named = preset(settings.get("learner", LEGACY_LEARNER))
        learner = ERSAC(
            np.asarray(settings["theta0"], dtype=float),
            np.asarray(settings["sigma"], dtype=float),
            float(settings["eta"]),
            float(settings["kappa"]),
            float(settings["epsilon"]),
            np.column_stack([spec.lower, spec.upper]),
            lr_range=tuple(settings["lr_range"]),
            seed=int(settings["seed"]),
            weights=CostWeights(dict(settings["weights"])),
            max_step=settings.get("max_step", named.max_step),
            interleave_every=int(settings.get("interleave_every", 0)),
            greedy=named.greedy,
        )
        if "prior" in settings:  # the simulator's landscape as the critic's prior mean
            from ersac_hil.learner.prior import SimPrior
            learner.set_critic_prior(SimPrior.from_dict(settings["prior"]).critic_prior())
        return cls(task, learner)

    @classmethod
    def restore(cls, task: str, settings: Mapping[str, Any],
                observations: Sequence[tuple[Sequence[float], Mapping[str, float]]],
                kappa: float, weights: Mapping[str, float], theta: Sequence[float],
                state: Mapping[str, Any] | None) -> Engine:
        """The learner after the last stored update (see module doc).

        Args:
            observations: (executed theta, cost terms) of every ok episode, in order.
            kappa, weights, theta: the values in effect now.
            state: ``ERSAC.get_state()`` stored with the last update; ``None`` if none yet.
        """
        if state is None:
            if observations:
                raise ValueError("observations without a learner state")
            engine = cls.create(task, {**settings, "kappa": kappa, "weights": dict(weights),
                                       "theta0": list(theta)})
            return engine
        state = dict(state)
        state["theta"] = [float(v) for v in theta]
        learner = ERSAC.from_state(state)
        for x, terms in observations:
            learner.observe(np.asarray(x, dtype=float), dict(terms))
        engine = cls(task, learner)
        engine.set_weights(weights)
        engine.set_kappa(kappa)
        return engine

    # ------------------------------------------------------------------ state
    @property
    def theta(self) -> tuple[float, ...]:
        return _tuple(self._learner.theta)

    @property
    def sigma(self) -> tuple[float, ...]:
        return _tuple(self._learner.sigma)

    @property
    def kappa(self) -> float:
        return self._learner.kappa

    @property
    def weights(self) -> dict[str, float]:
        """Complete weights in the task's term order."""
        w = self._learner.weights
        return {k: float(w[k]) for k in self.spec.term_names}

    @property
    def n_observations(self) -> int:
        return self._learner.n_observations

    def snapshot(self) -> dict[str, Any]:
        """JSON-able learner state (stored with each update)."""
        return self._learner.get_state()

    def cost(self, terms: Mapping[str, float]) -> float:
        """The cost of ``terms`` under the current weights, exactly as the learner computes it."""
        return float(self._learner.weights.combine(dict(terms)))

    # ------------------------------------------------------------------ ask / tell
    def propose(self, k: int = 1) -> tuple[Proposal, ...]:
        """Draw k perturbations of the policy mean (idempotent until :meth:`learn`)."""
        base = self._learner.theta
        return tuple(self._proposal(base, x) for x in self._learner.ask_batch(k))

    def redraw(self, i: int) -> Proposal:
        """The agent refused the parameters of proposal ``i``: a new draw for it alone (the
        RNG has moved on, deterministically)."""
        return self._proposal(self._learner.theta, self._learner.reask(i))

    @staticmethod
    def _proposal(base: np.ndarray, executed: np.ndarray) -> Proposal:
        return Proposal(_tuple(base), _tuple(executed - base), _tuple(executed))

    def learn(self, proposals: Sequence[Proposal], terms: Sequence[Mapping[str, float]], *, run_id: str,
              idx: int, episode_ids: Sequence[str], stamp_s: float) -> UpdateRecord:
        """Tell the learner the cost terms of the proposals' episodes (in proposal order); the
        update as stored (``idx``: the update's index)."""
        u = self._learner.tell_batch(np.array([p.theta for p in proposals], dtype=float),
                                     [dict(t) for t in terms])
        self.last_skipped = u.skipped
        opt = lambda v: None if v is None else float(v)  # noqa: E731
        return UpdateRecord(
            run_id=run_id, idx=idx, episode_id=episode_ids[-1], episodes=tuple(episode_ids),
            theta_before=_tuple(u.theta_before), theta_after=_tuple(u.theta_after),
            cost=float(u.cost), J=opt(u.J_tilde), r=opt(u.r_tilde), r_z=opt(u.r_tilde_perturbed),
            td_error=opt(u.td_error), kappa=float(u.kappa), lr=float(u.step_size),
            state=self.snapshot(), stamp_s=stamp_s)

    # ------------------------------------------------------------------ changes
    @property
    def min_observations(self) -> int:
        """Episodes before the learner's first update (its warm-up)."""
        return self._learner.min_observations

    @property
    def observed_costs(self) -> list[float]:
        """The cost of every observation so far, in order (current weights)."""
        return [float(c) for c in self._learner.observations.costs]

    @property
    def observed_damage(self) -> list[bool] | None:
        """Whether each observation so far damaged the robot (its ``damage`` cost term above
        0), in order; None where the task has no ``damage`` term."""
        obs = self._learner.observations
        names = list(obs.weights.names)
        if "damage" not in names:
            return None
        return [bool(v) for v in damaged(dict(zip(names, obs.terms.T)))]

    def set_kappa(self, kappa: float) -> None:
        self._learner.kappa = float(kappa)

    def set_weights(self, weights: Mapping[str, float]) -> None:
        """Complete new weights; every stored observation is re-costed by the learner."""
        self._learner.reweight(CostWeights(dict(weights)))

    def check_weights(self, weights: Mapping[str, float]) -> None:
        """Raise ``ValueError`` unless every weight is within ``[0, MAX_WEIGHT]`` and the
        weighted cost of every stored episode is finite (beyond that the costs are unusable
        for the critic)."""
        big = {k: v for k, v in weights.items() if not (0.0 <= float(v) <= MAX_WEIGHT)}
        if big:
            raise ValueError(f"weights must be within [0, {MAX_WEIGHT:g}], got {big}")
        w = CostWeights(dict(weights))
        observations = self._learner.observations
        if len(observations) and set(w.names) == set(observations.weights.names):
            with np.errstate(over="ignore", invalid="ignore"):
                costs = w.combine_rows(np.asarray(observations.terms))
            bad = np.flatnonzero(~np.isfinite(costs))
            if bad.size:
                raise ValueError(f"these weights make the cost of {bad.size} stored episode(s) "
                                 f"non-finite (first: episode {int(bad[0]) + 1})")

    def drop_critic_prior(self) -> None:
        """The critic sees the robot's episodes only from now on (a rejected prior)."""
        if self._learner.critic_prior is not None:
            self._learner.set_critic_prior(None)

    def adopt(self, theta: Sequence[float]) -> None:
        """Make ``theta`` the policy mean (no pending proposal allowed)."""
        self._learner.theta = [float(v) for v in theta]

    # ------------------------------------------------------------------ critic / selection
    def critic(self, points: Sequence[Sequence[float]]) -> list[tuple[float, float]]:
        """(J~, r~) at every point, each from the VHGP of the point's neighbourhood."""
        out = []
        try:
            for p in points:
                e = self._learner.critic_estimate(np.asarray(p, dtype=float))
                out.append((float(e.J), float(e.r)))
        except InsufficientDataError as exc:
            raise NotEnoughData(str(exc)) from exc
        return out

    def select(self, kappa: float, weights: Mapping[str, float] | None = None, pessimism: float = 0.0
               ) -> tuple[tuple[float, ...], float, float]:
        """Offline selection: argmin of F~ = J~ + kappa r~ in the data's trust region, under
        ``weights`` (default: the current ones; the learner's own weights are restored
        exactly afterwards). Returns (theta, J~, r~)."""
        current = self.weights
        temporary = weights is not None and dict(weights) != current
        try:
            if temporary:
                self.set_weights(weights)
            sel = self._learner.select(float(kappa), pessimism=pessimism) if pessimism else \
                self._learner.select(float(kappa))
        except InsufficientDataError as exc:
            raise NotEnoughData(str(exc)) from exc
        finally:
            if temporary:
                self.set_weights(current)
        return _tuple(sel.theta), float(sel.J_tilde), float(sel.r_tilde)

