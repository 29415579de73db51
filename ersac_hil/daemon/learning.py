"""The open run: its learner (``Engine``) and its store, kept consistent under one lock.

The learning loop and the control-plane handlers both change the run; every change goes
through here, so what the learner believes and what the store holds never disagree:

- :meth:`LearningRun.propose` / :meth:`LearningRun.redraw` open a proposal (the learner's
  pending ask); :meth:`LearningRun.commit_success` tells the learner and commits the episode
  with its update in one transaction, closing the proposal.
- An adopted selection (:meth:`LearningRun.adopt`) never lands between an ask and its tell:
  while a proposal is open it waits and is applied right after the commit (or before the
  next proposal).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Sequence

from protocol.zenoh import EpisodeRequest, EpisodeResult

from .config import DaemonConfig
from .engine import Engine, Proposal
from .runs import open_run, rebuild_engine
from .store import RunRecord, Store, UpdateRecord

__all__ = ["LearningRun"]


class LearningRun:
    """The run ``config`` opens or resumes in ``store`` (see ``runs.open_run``).

    Attributes:
        store, run, config (effective, after resume), engine, resumed, interrupted (attempts
        found pending at start and marked ``interrupted``), n_updates, status (the daemon
        status reported in ``LearnerState``). ``lock`` guards engine + store consistency.
    """

    def __init__(self, store: Store, config: DaemonConfig) -> None:
        self.store = store
        self.run: RunRecord
        self.run, self.config, self.resumed = open_run(store, config)
        self.interrupted = store.interrupt_pending(self.run.run_id, "daemon died while pending")
        self.engine: Engine = rebuild_engine(store, self.run)
        self.n_updates = store.update_count(self.run.run_id)
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
    def propose(self) -> Proposal:
        """Open the next proposal (applying an adoption that was waiting)."""
        with self.lock:
            self._apply_pending_adopt()
            proposal = self.engine.propose()
            self._proposal_open = True
            return proposal

    def redraw(self) -> Proposal:
        """The agent refused the open proposal's parameters: draw another one."""
        with self.lock:
            self.engine.discard()
            return self.engine.propose()

    def commit_success(self, idx: int, request: EpisodeRequest, result: EpisodeResult,
                       proposal: Proposal) -> UpdateRecord:
        """Tell the learner, commit the episode and its update together, close the proposal."""
        with self.lock:
            update = self.engine.learn(proposal, dict(result.cost_terms), run_id=self.run_id,
                                       idx=idx, episode_id=request.episode_id, stamp_s=time.time())
            self.store.record_success(request.episode_id, result, update.cost, update)
            self.n_updates = idx + 1
            self._proposal_open = False
            self._apply_pending_adopt()
        return update

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
