"""The learner daemon: ERSAC driven against the agent's ``episode/run``, one episode at a time.

Lifecycle (``ersac_hil.lifecycle.serve``): ``start()`` opens the store, opens or resumes the
run (``learning.LearningRun``), connects to Zenoh, links to the agent (``agents.AgentLink``),
declares the control plane (``control.ControlPlane`` serving ``handlers.ControlHandlers``) and
starts the learning thread; ``stop()`` cancels an in-flight query (the attempt is recorded
``interrupted``), joins the thread and closes everything. ``finished`` is set when the run
is over (and the daemon does not linger), which ends ``serve``.

Episode loop, for learner episode ``idx`` (= number of updates so far):

1. ``engine.propose()`` draws z and gives the executed theta; the scenario seed is derived
   from the run seed and ``idx`` (:func:`scenario_seed`), so a retried or resumed request is
   the same request.
2. Wait until the agent's liveliness token is present (backoff is cut short when it comes).
3. Commit a ``pending`` attempt, then query ``episode/run`` with a timeout.
4. ``ok``: tell the learner, then commit the episode with its update in one transaction,
   publish it on ``learner/episodes``, print a progress line, next idx.
   Anything else (fault status, timeout, lost agent, refusal, bad reply): commit the attempt
   with its status (never told to the learner) and retry the same request with a new episode
   id after a backoff (doubling from ``backoff_s[0]`` up to ``backoff_s[1]``). After
   ``max_attempts`` failed attempts of one request, or at once on an ``unknown_task``
   refusal, the run is marked ``failed``. An ``invalid_request`` refusal means the agent will
   not execute these parameters (e.g. a spline outside the joint limits): the perturbation is
   discarded and a new one drawn around the same policy mean (at most ``MAX_REDRAWS`` in a
   row; the refusal is deterministic, so a resumed run redraws exactly the same way).
"""
from __future__ import annotations

import logging
import sys
import threading
import time
from typing import TextIO

import zenoh

from ersac_hil.zenoh_session import open_session, resolve_config
from protocol.zenoh import EpisodeRequest, EpisodeResult, LearnerEpisode

from .agents import AgentAbsent, AgentLink, Stopped
from .config import DaemonConfig
from .control import ControlPlane
from .engine import Proposal
from .handlers import ControlHandlers
from .learning import LearningRun
from .runs import episode_id, scenario_seed
from .store import Store

__all__ = ["Daemon", "RunFailed", "EXIT_FAILED", "EXIT_NO_AGENT", "MAX_REDRAWS"]

log = logging.getLogger(__name__)

#: Exit status when the run failed (too many failed attempts, contract mismatch).
EXIT_FAILED = 3
#: Exit status when the agent stayed absent longer than ``agent_wait_s`` (run resumable).
EXIT_NO_AGENT = 4
#: Perturbations of one episode the agent may refuse (``invalid_request``) before the run fails.
MAX_REDRAWS = 20


class RunFailed(RuntimeError):
    """The run cannot continue; the store marks it failed."""


def _fmt(values) -> str:  # noqa: ANN001
    vals = [f"{v:.4f}" for v in values]
    return vals[0] if len(vals) == 1 else "[" + ", ".join(vals) + "]"


class Daemon:
    """The learner daemon service (``start``/``stop``): lifecycle and the learning loop.

    After ``start()``: ``learning`` (the open run), ``handlers`` (the control plane's),
    ``control``, ``agents``; ``config`` is the effective configuration (a resumed run's
    stored learner settings)."""

    def __init__(self, config: DaemonConfig, out: TextIO | None = None) -> None:
        self.config = config
        self.keys = config.keys
        self.out = out if out is not None else sys.stdout
        self.finished = threading.Event()
        self.exit_code = 0
        self._stop = threading.Event()
        self.store: Store | None = None
        self.learning: LearningRun | None = None
        self.handlers: ControlHandlers | None = None
        self.session: zenoh.Session | None = None
        self.agents: AgentLink | None = None
        self.control: ControlPlane | None = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self.store = Store(self.config.db)
        self.learning = learning = LearningRun(self.store, self.config)
        self.config = learning.config
        self.handlers = ControlHandlers(learning, self._print)
        self.session = open_session(resolve_config(self.config.zenoh_options, connect_timeout_s=10.0),
                                    insecure=self.config.insecure)
        self.agents = AgentLink(self.session, self.keys, self.config.episode_timeout_s, self._stop)
        self.control = ControlPlane(self.session, self.keys, self.handlers)
        run, engine, interrupted = learning.run, learning.engine, learning.interrupted
        how = (f"resumed at episode {learning.n_updates + 1}" + (f", {interrupted} interrupted attempt(s)"
               if interrupted else "")) if learning.resumed else "new"
        self._print(f"run {run.run_id} ({how}): {self.config.task} on {self.config.robot}, "
                    f"kappa {engine.kappa:g}, {learning.budget} episodes, seed {run.seed}, "
                    f"store {self.config.db}")
        self._thread = threading.Thread(target=self._main, name="learner-loop", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Idempotent; interrupts a waiting or running episode (recorded ``interrupted``)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self.agents is not None:
            self.agents.wake()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
        if self.control is not None:
            self.control.close()
        if self.agents is not None:
            self.agents.close()
        if self.session is not None:
            self.session.close()
        if self.store is not None:
            self.store.close()

    def _print(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    # ------------------------------------------------------------------ learning loop
    def _main(self) -> None:
        learning = self.learning
        try:
            learning.status = "running"
            while learning.n_updates < learning.budget:
                if self._stop.is_set():
                    return
                self._learn_one()
            learning.finish()
            learning.status = "idle"
            self._print(f"run {learning.run_id} finished: {learning.n_updates} episodes, "
                        f"theta {_fmt(learning.engine.theta)}, kappa {learning.engine.kappa:g}")
            if not self.config.linger:
                self.finished.set()
        except Stopped:
            learning.status = "stopped"
        except AgentAbsent as exc:
            self._print(f"giving up: {exc}; the run stays resumable")
            self.exit_code = EXIT_NO_AGENT
            learning.status = "paused"
            self.finished.set()
        except RunFailed as exc:
            self._print(f"run {learning.run_id} failed: {exc}")
            learning.fail(str(exc))
            self.exit_code = EXIT_FAILED
            learning.status = "failed"
            self.finished.set()
        except Exception as exc:  # noqa: BLE001
            log.exception("learning loop crashed")
            self._print(f"learning loop crashed: {type(exc).__name__}: {exc}")
            self.exit_code = 1
            learning.status = "failed"
            self.finished.set()

    def _wait_for_agent(self) -> None:
        if self.agents.ready():
            return
        self._print(f"waiting for the agent ({self.keys.agent_alive}) ...")
        self.learning.status = "paused"
        self.agents.wait_ready(self.config.agent_wait_s)
        self.learning.status = "running"
        self._print("agent is alive")

    def _learn_one(self) -> None:
        learning, store, run_id = self.learning, self.store, self.learning.run_id
        idx = learning.n_updates
        proposal = learning.propose()
        seed = scenario_seed(learning.run.seed, idx)
        attempts = store.attempts_of(run_id, idx)
        attempt = attempts[-1].attempt + 1 if attempts else 0
        failures = redraws = 0
        backoff = self.config.backoff_s[0]
        while True:
            self._wait_for_agent()
            eid = episode_id(run_id, idx, attempt)
            request = EpisodeRequest(eid, self.config.task, proposal.theta, seed)
            store.begin_attempt(run_id, eid, idx, attempt, proposal.base_theta, proposal.z,
                                proposal.theta, seed)
            outcome = self.agents.run(request)
            if outcome.status == "ok":
                update = learning.commit_success(idx, request, outcome.result, proposal)
                self._publish(idx, request, outcome.result, proposal, update.cost)
                skipped = learning.engine.last_skipped
                critic = (f"update skipped ({skipped})" if skipped else "J~ (warm-up)  r~ (warm-up)"
                          if update.warmup else f"J~ {update.J:.4f}  r~ {update.r:.4f}")
                self._print(f"episode {idx + 1:4d}/{learning.budget}  theta {_fmt(update.theta_before)} -> "
                            f"{_fmt(update.theta_after)}  executed {_fmt(proposal.theta)}  "
                            f"cost {update.cost:.4f}  {critic}  kappa {update.kappa:g}")
                return
            store.record_failure(eid, outcome.status, outcome.detail, outcome.result)
            self._publish(idx, request, outcome.result, proposal, None)
            if outcome.status == "interrupted":
                raise Stopped
            attempt += 1
            if outcome.code == "unknown_task":
                raise RunFailed(f"agent refused episode {eid}: {outcome.code}: {outcome.detail}")
            if outcome.code == "invalid_request":
                # the agent refuses these parameters (e.g. a spline outside the joint limits):
                # they are infeasible; draw a new perturbation around the same policy mean
                redraws += 1
                if redraws > MAX_REDRAWS:
                    raise RunFailed(f"episode {idx + 1}: the agent refused {redraws} perturbations in "
                                    f"a row, last: {outcome.detail}")
                proposal = learning.redraw()
                self._print(f"episode {idx + 1:4d} attempt {attempt}: refused ({outcome.detail[:200]}) "
                            "- drawing a new perturbation")
                continue
            failures += 1
            if failures >= self.config.max_attempts:
                raise RunFailed(f"episode {idx + 1}: {failures} failed attempts, last {outcome.status}: "
                                f"{outcome.detail}")
            self._print(f"episode {idx + 1:4d} attempt {attempt}: {outcome.status} "
                        f"({outcome.detail[:200]}) - retrying in {backoff:g} s")
            self.agents.sleep(backoff)
            backoff = min(2 * backoff, self.config.backoff_s[1])

    def _publish(self, idx: int, request: EpisodeRequest, result: EpisodeResult | None,
                 proposal: Proposal, cost: float | None) -> None:
        if result is None or self.control is None:
            return
        try:
            self.control.publish_episode(LearnerEpisode(
                self.learning.run_id, idx, proposal.base_theta, proposal.z, request, result, cost,
                time.time()))
        except Exception:  # noqa: BLE001 - a publication must never stop learning
            log.exception("cannot publish episode %s", request.episode_id)
