"""The open run: its learner (``Engine``) and its store, kept consistent under one lock.

The learning loop and the control-plane handlers both change the run; every change goes
through here, so what the learner believes and what the store holds never disagree:

- :meth:`LearningRun.propose` opens the next batch of proposals (the learner's pending ask of
  ``batch`` perturbations; fewer for the last batch of the budget), :meth:`LearningRun.redraw`
  replaces one the agent refused; :meth:`LearningRun.commit_ok` commits an ok episode whose
  batch is not complete; :meth:`LearningRun.commit_update` tells the learner the whole batch
  and commits the update with the episode that completed it in one transaction, closing the
  proposal. With ``batch`` 1 every ok episode is committed with its update.
- An adopted selection (:meth:`LearningRun.adopt`) never lands between an ask and its tell:
  while a proposal is open it waits and is applied right after the commit (or before the
  next proposal).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Mapping, Sequence

from protocol.zenoh import EpisodeResult

from .config import DaemonConfig
from .engine import Engine, Proposal
from .runs import open_run, rebuild_engine
from .store import RunRecord, Store, UpdateRecord

__all__ = ["LearningRun"]


class LearningRun:
    """The run ``config`` opens or resumes in ``store`` (see ``runs.open_run``).

    Attributes:
        store, run, config (effective, after resume), engine, resumed, interrupted (attempts
        found pending at start and marked ``interrupted``), n_updates, n_episodes (ok
        episodes told to the learner), batch, status (the daemon status reported in
        ``LearnerState``). ``lock`` guards engine + store consistency.
    """

    def __init__(self, store: Store, config: DaemonConfig) -> None:
        self.store = store
        self.run: RunRecord
        self.run, self.config, self.resumed = open_run(store, config)
        self.interrupted = store.interrupt_pending(self.run.run_id, "daemon died while pending")
        self.engine: Engine = rebuild_engine(store, self.run)
        self.n_updates = store.update_count(self.run.run_id)
        self.n_episodes = sum(e.update_idx is not None for e in store.ok_episodes(self.run.run_id))
        self.batch = int(self.run.settings.get("batch", 1))
        self.status = "idle"
        self.lock = threading.RLock()
        self._proposal_open = False
        self._pending_adopt: tuple[float, ...] | None = None

    @property
    def run_id(self) -> str:
        return self.run.run_id

    @property
    def budget(self) -> int:
        """Total learner episodes of the run."""
        return int(self.run.settings["episodes"])

    # ------------------------------------------------------------------ the learning loop's side
    def propose(self) -> tuple[Proposal, ...]:
        """Open the next batch: ``batch`` proposals for episodes ``n_episodes``, ... (fewer
        if the budget ends first), applying an adoption that was waiting."""
        with self.lock:
            self._apply_pending_adopt()
            proposals = self.engine.propose(min(self.batch, self.budget - self.n_episodes))
            self._proposal_open = True
            return proposals

    def redraw(self, i: int) -> Proposal:
        """The agent refused the parameters of the open batch's proposal ``i``: another one."""
        with self.lock:
            return self.engine.redraw(i)

    def commit_ok(self, episode_id: str, result: EpisodeResult) -> float:
        """Commit an ok episode of an incomplete batch; returns its cost (current weights)."""
        with self.lock:
            cost = self.engine.cost(result.cost_terms)
            self.store.record_ok(episode_id, result, cost)
            return cost

    def commit_update(self, proposals: Sequence[Proposal], terms: Sequence[Mapping[str, float]],
                      episode_ids: Sequence[str], completing: EpisodeResult | None) -> UpdateRecord:
        """Tell the learner the batch (``terms`` and ``episode_ids`` in proposal order), commit
        the update with the episode ``completing`` it (``None``: all are committed already) in
        one transaction, close the proposal."""
        with self.lock:
            update = self.engine.learn(proposals, terms, run_id=self.run_id, idx=self.n_updates,
                                       episode_ids=episode_ids, stamp_s=time.time())
            if completing is None:
                self.store.record_success(None, None, None, update)
            else:
                self.store.record_success(completing.episode_id, completing,
                                          self.engine.cost(completing.cost_terms), update)
            self.n_updates += 1
            self.n_episodes += len(proposals)
            self._proposal_open = False
            self._apply_pending_adopt()
            if self.n_episodes == self.engine.min_observations and "prior" in self.run.settings:
                self._check_prior()
            if self.n_episodes >= self.budget:
                self._final_selection()
        return update

    def _check_prior(self) -> None:
        """After the warm-up (every episode so far drawn around the prior's start): drop a
        simulator prior the robot disagrees with, i.e. go on from the task's default start
        (a theta change with source ``prior rejected: <why>``) with a critic that sees the
        robot's episodes only."""
        from ersac_hil.learner.prior import SimPrior

        from .config import task_defaults
        prior = SimPrior.from_dict(self.run.settings["prior"])
        damaged = self.engine.observed_damage
        ok, why = prior.consistent(self.engine.observed_costs[: self.n_episodes],
                                   None if damaged is None else damaged[: self.n_episodes])
        if ok:
            return
        theta = task_defaults(self.run.task).theta0
        self.engine.adopt(theta)
        self.engine.drop_critic_prior()
        self.store.record_change(self.run_id, "theta", list(theta), f"prior rejected: {why}", self.n_updates)

    def _final_selection(self) -> None:
        """The learner preset's final policy (``presets.LearnerPreset.final_selection``): at a
        kappa > 0 the offline selection of that kappa over the run's episodes (pessimism
        kappa), adopted and recorded as a theta change (source ``final selection``) after the
        last update."""
        from ersac_hil.learner.presets import LEGACY_LEARNER, preset

        from .engine import NotEnoughData
        kappa = self.engine.kappa
        if not preset(self.run.settings.get("learner", LEGACY_LEARNER)).final_selection or kappa <= 0:
            return
        try:
            theta, _, _ = self.engine.select(kappa, pessimism=kappa)
        except NotEnoughData:
            return
        self.engine.adopt(theta)
        self.store.record_change(self.run_id, "theta", list(theta), "final selection", self.n_updates)

    def finish(self) -> None:
        self.store.set_run_status(self.run_id, "finished")

    def fail(self, detail: str) -> None:
        self.store.set_run_status(self.run_id, "failed", detail)

    # ------------------------------------------------------------------ the handlers' side
    def adopt(self, theta: Sequence[float]) -> None:
        """Make ``theta`` the policy mean now, or right after the open proposal's commit."""
        with self.lock:
            self._pending_adopt = tuple(theta)
            if not self._proposal_open:
                self._apply_pending_adopt()

    def _apply_pending_adopt(self) -> None:
        theta, self._pending_adopt = self._pending_adopt, None
        if theta is not None:
            self.engine.adopt(theta)
            self.store.record_change(self.run_id, "theta", list(theta), "select", self.n_updates)
