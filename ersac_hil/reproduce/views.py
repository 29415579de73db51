"""What the stores say: learning histories, the critic as it was after n episodes, and a
global VHGP fit of a cost distribution (the paper's Fig. 2).

``history(db)`` reads a learning run; ``engine_after(db, n)`` rebuilds the learner exactly as
it was after its n-th update (``Engine.restore`` with the state stored with that update and
the first n episodes); ``critic_curve`` evaluates its critic on a 1-D grid, NaN where the
critic has too few neighbours; ``global_fit`` fits one VHGP to all given points.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ersac_hil.critic import VHGP, CriticError
from ersac_hil.daemon.engine import Engine, NotEnoughData
from ersac_hil.daemon.store import RunRecord, Store
from protocol.zenoh import damaged

__all__ = ["History", "history", "engine_after", "critic_curve", "global_fit"]


@dataclass(frozen=True)
class History:
    """A learning run: ``theta`` executed per ok episode (n, d), ``cost`` (n,) under the
    weights in effect, ``terms`` per episode, ``damage`` (n,) flags, ``theta_after`` (n, d)
    the policy mean after each update, ``theta0`` (d,), ``changes`` (kind, value, n_updates)."""

    run: RunRecord
    theta: np.ndarray
    cost: np.ndarray
    terms: list[Mapping[str, float]]
    damage: np.ndarray
    theta_after: np.ndarray
    theta0: np.ndarray
    changes: list[tuple[str, object, int]]

    @property
    def n(self) -> int:
        return len(self.cost)

    @property
    def final_policy(self) -> np.ndarray:
        """The policy mean at the end of the run, (d,): a theta adopted after the last update
        (the ``select`` learner's final selection, an operator's adoption), else the last
        update's."""
        n = len(self.theta_after)
        for kind, value, at in reversed(self.changes):
            if kind == "theta" and at >= n:
                return np.asarray(value, dtype=float)
        return self.policy_after(n)

    def policy_after(self, n: int) -> np.ndarray:
        """The policy mean after ``n`` updates (``theta0`` for n = 0), shape (d,)."""
        return self.theta0 if n == 0 else self.theta_after[n - 1]


def history(db: Path) -> History:
    """The last run in the store ``db``."""
    with Store(db, readonly=True) as store:
        run = store.runs()[-1]
        eps = store.ok_episodes(run.run_id)
        ups = store.updates(run.run_id)
        changes = [(c.kind, c.value, c.n_updates) for c in store.changes(run.run_id)]
    d = len(run.settings["theta0"])
    return History(
        run, np.array([e.theta for e in eps], dtype=float).reshape(-1, d),
        np.array([e.cost for e in eps], dtype=float),
        [dict(e.cost_terms or {}) for e in eps],
        np.array([bool((e.failures or {}).get("hardware_damage")) or
                  bool(damaged(e.cost_terms or {})) for e in eps]),
        np.array([u.theta_after for u in ups], dtype=float).reshape(-1, d),
        np.array(run.settings["theta0"], dtype=float), changes)


def engine_after(db: Path, n: int, weights: Mapping[str, float] | None = None) -> Engine:
    """The learner of the store's last run right after its ``n``-th update (n >= 1)."""
    with Store(db, readonly=True) as store:
        run = store.runs()[-1]
        eps = store.ok_episodes(run.run_id)[:n]
        ups = store.updates(run.run_id)
        if not 1 <= n <= len(ups):
            raise ValueError(f"run {run.run_id} has {len(ups)} updates, asked for {n}")
        u = ups[n - 1]
    s = run.settings
    return Engine.restore(run.task, s, observations=[(e.theta, e.cost_terms) for e in eps],
                          kappa=u.kappa, weights=dict(weights if weights is not None else s["weights"]),
                          theta=u.theta_after, state=dict(u.state))


def critic_curve(engine: Engine, grid: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """J~ and r~ of a 1-D task's critic at every grid point, shape (m,) each; NaN where the
    critic's neighbourhood is too small."""
    J = np.full(len(grid), math.nan)
    r = np.full(len(grid), math.nan)
    for i, x in enumerate(grid):
        try:
            ((J[i], r[i]),) = engine.critic([(float(x),)])
        except NotEnoughData:
            pass
    return J, r


def global_fit(x: Sequence[float], y: Sequence[float], grid: Sequence[float]
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """One VHGP on all points (x (n,), y (n,)): mean and noise std on ``grid`` (m,), or
    ``None`` if the fit fails (too few points)."""
    X = np.asarray(x, dtype=float).reshape(-1, 1)
    try:
        pred = VHGP().fit(X, np.asarray(y, dtype=float)).predict(np.asarray(grid, dtype=float).reshape(-1, 1))
    except (CriticError, ValueError, np.linalg.LinAlgError):
        return None
    return pred.f_mean, pred.noise_std
