"""The learner daemon: ERSAC driven against the ``episode/run`` of one agent or a fleet.

Lifecycle (``ersac_hil.lifecycle.serve``): ``start()`` checks an existing store read-only
(``runs.check_store``: another robot's or task's store, an unknown run id... are refused
before anything is written), connects to Zenoh, then opens (creates) the store and opens or
resumes the run (``learning.LearningRun``), links to the agents (``fleet.Fleet``: one
``agents.AgentLink`` per robot of ``--robot``, names or key expressions), declares the control
plane (``control.ControlPlane`` serving ``handlers.ControlHandlers``) and starts the learning
thread; ``stop()`` cancels the in-flight queries (their attempts are recorded
``interrupted``), joins the thread and closes everything. ``finished`` is set when the run
is over (and the daemon does not linger), which ends ``serve``.

Learning loop, one update at a time, over a batch of k = ``batch`` learner episodes
``n, ..., n + k - 1`` (n = ok episodes told so far; k = 1 is the paper's Algorithm 1):

1. ``learning.propose()`` draws k perturbations of the policy mean; the scenario seed of
   episode idx is derived from the run seed and idx (:func:`scenario_seed`), so a retried,
   re-sent or resumed request is the same request, whichever agent runs it.
2. Each request is committed as a ``pending`` attempt and queued; the first free agent whose
   presence tokens are up takes it (while none is, the state is ``paused``).
3. ``ok``: the episode is committed (an incomplete batch: alone; the one completing it:
   together with the update, in one transaction: the learner is told the k episodes in idx
   order and the store records which episodes fed the update), published on
   ``learner/episodes`` and a progress line printed.
   Anything else (fault status, timeout, lost agent, refusal, bad reply): the attempt is
   committed with its status (never told to the learner) and the same request re-queued with
   a new episode id, after a backoff (doubling from ``backoff_s[0]`` up to ``backoff_s[1]``;
   none when its agent vanished: another may take it at once). An episode ended ``stopped`` by
   an e-stop, or refused ``unavailable`` (e-stop engaged, robot not commissioned), is no failure:
   the run is ``paused`` and asks again, uncounted. After ``max_attempts`` failed
   attempts of one episode, or at once on an ``unknown_task`` refusal, the run is marked
   ``failed``. An ``invalid_request`` refusal means the agent will not execute these
   parameters (e.g. a spline outside the joint limits): once every other episode of the batch
   has ended, each refused one gets a new perturbation around the same policy mean, in idx
   order (at most ``MAX_REDRAWS`` in a row per episode; refusals are deterministic, so a
   resumed or re-run batch redraws exactly the same way).
4. A resumed daemon re-uses the ok episodes of an incomplete batch whose parameters are those
   the learner draws again (the same random stream), so nothing recorded is run twice.
"""
from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TextIO

import zenoh

from ersac_hil.zenoh_session import open_session, resolve_config
from protocol.zenoh import EpisodeRequest, EpisodeResult, LearnerEpisode

from .agents import AgentAbsent, Outcome, Stopped
from .config import DaemonConfig
from .control import ControlPlane
from .engine import Proposal
from .fleet import Finished, Fleet
from .handlers import ControlHandlers
from .learning import LearningRun
from .runs import check_store, episode_id, scenario_seed
from .store import Store, StoreError, StoreUnwritable, UpdateRecord

__all__ = ["Daemon", "RunFailed", "EXIT_FAILED", "EXIT_NO_AGENT", "EXIT_STORE", "MAX_REDRAWS"]

log = logging.getLogger(__name__)

#: Exit status when the run failed (too many failed attempts, contract mismatch).
EXIT_FAILED = 3
#: Exit status when the agent stayed absent longer than ``agent_wait_s`` (run resumable).
EXIT_NO_AGENT = 4
#: Exit status when the store could not be written (disk full, I/O error): the run stops at
#: once, nothing half-written; it is resumable once the cause is gone.
EXIT_STORE = 5
#: Perturbations of one episode the agent may refuse (``invalid_request``) before the run fails.
MAX_REDRAWS = 20


class RunFailed(RuntimeError):
    """The run cannot continue; the store marks it failed."""


def _fmt(values) -> str:  # noqa: ANN001
    vals = [f"{v:.4f}" for v in values]
    return vals[0] if len(vals) == 1 else "[" + ", ".join(vals) + "]"


@dataclass
class _Member:
    """One learner episode of the open batch: ``i``-th proposal, episode ``idx``."""

    i: int
    idx: int
    proposal: Proposal
    seed: int
    attempt: int
    terms: Mapping[str, float] | None = None  # cost terms once ok
    episode_id: str = ""  # of the ok attempt
    failures: int = 0
    redraws: int = 0
    backoff: float = 0.0
    refusal: str = ""  # the agent's reason of the last refusal


class Daemon:
    """The learner daemon service (``start``/``stop``): lifecycle and the learning loop.

    After ``start()``: ``learning`` (the open run), ``handlers`` (the control plane's),
    ``control``, ``fleet``; ``config`` is the effective configuration (a resumed run's
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
        self.fleet: Fleet | None = None
        self.control: ControlPlane | None = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        # nothing is written before the daemon can run: an existing store is checked read-only
        # first, the store (its directory, the run) is created only once the session is open
        check_store(self.config)
        self.session = open_session(resolve_config(self.config.zenoh_options, default_connect_timeout_s=10.0),
                                    insecure=self.config.insecure)
        self.store = Store(self.config.db)
        self.learning = learning = LearningRun(self.store, self.config)
        self.config = learning.config
        self.handlers = ControlHandlers(learning, self._print)
        self.fleet = Fleet(self.session, self.config.prefix, self.config.sources,
                           self.config.episode_timeout_s, self._stop)
        self.control = ControlPlane(self.session, self.keys, self.handlers)
        run, engine, interrupted = learning.run, learning.engine, learning.interrupted
        how = (f"resumed at episode {learning.n_episodes + 1}" + (f", {interrupted} interrupted attempt(s)"
               if interrupted else "")) if learning.resumed else "new"
        on = self.config.robot if len(self.config.sources) == 1 else "fleet " + ", ".join(self.config.sources)
        batch = f", batch {learning.batch}" if learning.batch > 1 else ""
        self._print(f"run {run.run_id} ({how}): {self.config.task} on {on}, "
                    f"kappa {engine.kappa:g}, {learning.budget} episodes{batch}, seed {run.seed}, "
                    f"store {self.config.db}")
        self._thread = threading.Thread(target=self._main, name="learner-loop", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Idempotent; interrupts waiting or running episodes (recorded ``interrupted``)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self.fleet is not None:
            self.fleet.cancel()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
        if self.control is not None:
            self.control.close()
        if self.fleet is not None:
            self.fleet.close()
        if self.learning is not None:
            try:
                self.store.interrupt_pending(self.learning.run_id, "daemon stopped during the episode")
            except StoreError as exc:  # the next start marks them interrupted instead
                if self.exit_code != EXIT_STORE:  # (else the run's stop said why already)
                    log.warning("pending attempts left pending: %s", exc)
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
            while learning.n_episodes < learning.budget:
                if self._stop.is_set():
                    return
                self._learn_batch()
            learning.finish()
            learning.status = "idle"
            self._print(f"run {learning.run_id} finished: {learning.n_episodes} episodes, "
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
        except StoreUnwritable as exc:
            self._print(f"run {learning.run_id} stopped: {exc}; the run stays resumable")
            self.exit_code = EXIT_STORE
            learning.status = "stopped"
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

    def _learn_batch(self) -> None:
        """Run the next batch until its update is committed (see the module doc)."""
        learning, store, run_id = self.learning, self.store, self.learning.run_id
        first = learning.n_episodes
        members = []
        for i, proposal in enumerate(learning.propose()):
            idx = first + i
            attempts = store.attempts_of(run_id, idx)
            members.append(_Member(i, idx, proposal, scenario_seed(learning.run.seed, idx),
                                   attempts[-1].attempt + 1 if attempts else 0, backoff=self.config.backoff_s[0]))
        # a resumed daemon: ok episodes of this batch, committed before it stopped
        stored = {e.idx: e for e in store.ok_episodes(run_id) if e.update_idx is None}
        while True:
            for m in members:
                if m.terms is None:
                    done = stored.get(m.idx)
                    if done is not None and done.theta == m.proposal.theta:
                        m.terms, m.episode_id = dict(done.cost_terms), done.episode_id
                    else:
                        self._send(m, 0.0)
            refused = self._collect(members)
            if not refused:
                break
            for m in sorted(refused, key=lambda m: m.i):  # in idx order: deterministic draws
                m.proposal = learning.redraw(m.i)
                self._print(f"episode {m.idx + 1:4d} attempt {m.attempt}: refused ({m.refusal[:200]}) "
                            "- drawing a new perturbation")
        if all(m.terms is not None for m in members) and learning.n_episodes == first:
            # every episode was committed before (a resumed daemon whose batch shrank)
            self._commit(members, None)

    def _send(self, m: _Member, delay_s: float) -> None:
        """Queue member ``m``'s request; its ``pending`` attempt is committed by the agent's
        worker right before the query goes out."""
        run_id, eid, p = self.learning.run_id, episode_id(self.learning.run_id, m.idx, m.attempt), m.proposal
        self.fleet.submit(EpisodeRequest(eid, self.config.task, p.theta, m.seed), delay_s, lambda: (
            self.store.begin_attempt(run_id, eid, m.idx, m.attempt, p.base_theta, p.z, p.theta, m.seed)))

    def _collect(self, members: list[_Member]) -> list[_Member]:
        """Outcomes until no request of the batch is in flight; returns the refused members."""
        by_eid: dict[str, _Member] = {}
        for m in members:
            if m.terms is None:
                by_eid[episode_id(self.learning.run_id, m.idx, m.attempt)] = m
        refused: list[_Member] = []
        while by_eid:
            done = self._next_outcome()
            m = by_eid.pop(done.request.episode_id, None)
            if m is None:
                continue  # a stale outcome (a query of a stopped daemon)
            if done.error is not None:
                raise done.error
            outcome, request = done.outcome, done.request
            if outcome.status == "ok":
                if self.learning.status == "paused":  # the robot was held and runs again
                    self.learning.status = "running"
                m.terms, m.episode_id = dict(outcome.result.cost_terms), request.episode_id
                self._ok(members, m, request, outcome.result, done.robot)
                continue
            self.store.record_failure(request.episode_id, outcome.status, outcome.detail, outcome.result)
            self._publish(m, request, outcome.result, None)
            if outcome.status == "interrupted":
                raise Stopped
            m.attempt += 1
            if outcome.status == "stopped" or outcome.code == "unavailable":
                self._hold(m, outcome)
                by_eid[episode_id(self.learning.run_id, m.idx, m.attempt)] = m
                continue
            if outcome.code == "unknown_task":
                raise RunFailed(f"agent refused episode {request.episode_id}: {outcome.code}: {outcome.detail}")
            if outcome.code == "invalid_request":
                m.redraws += 1
                if m.redraws > MAX_REDRAWS:
                    raise RunFailed(f"episode {m.idx + 1}: the agent refused {m.redraws} perturbations in "
                                    f"a row, last: {outcome.detail}")
                m.refusal = outcome.detail
                refused.append(m)
                continue
            m.failures += 1
            if m.failures >= self.config.max_attempts:
                raise RunFailed(f"episode {m.idx + 1}: {m.failures} failed attempts, last {outcome.status}: "
                                f"{outcome.detail}")
            delay = 0.0 if outcome.status == "lost" else m.backoff
            self._print(f"episode {m.idx + 1:4d} attempt {m.attempt}: {outcome.status} "
                        f"({outcome.detail[:200]}) - " + (f"retrying in {delay:g} s" if delay else "re-sending"))
            if delay:
                m.backoff = min(2 * m.backoff, self.config.backoff_s[1])
            self._send(m, delay)
            by_eid[episode_id(self.learning.run_id, m.idx, m.attempt)] = m
        return refused

    def _hold(self, m: _Member, outcome: Outcome) -> None:
        """The robot is held by its operator (an e-stop ended the episode ``stopped``, or the agent
        refuses ``unavailable``: e-stop engaged, not commissioned): no failure of the episode and
        not counted against ``max_attempts``; the run is ``paused`` and re-sends the same request
        (backoff up to ``backoff_s[1]``) until the robot runs again or the daemon is stopped."""
        self.learning.status = "paused"
        delay = m.backoff
        m.backoff = min(2 * m.backoff, self.config.backoff_s[1])
        self._print(f"episode {m.idx + 1:4d} attempt {m.attempt}: robot held ({outcome.status}: "
                    f"{outcome.detail[:200]}) - paused, asking again in {delay:g} s (not counted as a failure)")
        self._send(m, delay)

    def _ok(self, members: list[_Member], m: _Member, request: EpisodeRequest, result: EpisodeResult,
            robot: str) -> None:
        """Commit an ok episode (with the update if it completes the batch), publish, print."""
        where = f"  on {robot}" if len(self.config.sources) > 1 else ""
        if any(o.terms is None for o in members):
            cost = self.learning.commit_ok(request.episode_id, result)
            self._publish(m, request, result, cost)
            waiting = sum(o.terms is None for o in members)
            self._print(f"episode {m.idx + 1:4d}/{self.learning.budget}  executed {_fmt(m.proposal.theta)}  "
                        f"cost {cost:.4f}{where}  (update {self.learning.n_updates + 1} waits for {waiting} more)")
            return
        update = self._commit(members, result)
        cost = self.learning.engine.cost(result.cost_terms)
        self._publish(m, request, result, cost)
        skipped = self.learning.engine.last_skipped
        critic = (f"update skipped ({skipped})" if skipped else "J~ (warm-up)  r~ (warm-up)"
                  if update.warmup else f"J~ {update.J:.4f}  r~ {update.r:.4f}")
        if len(members) == 1:
            self._print(f"episode {m.idx + 1:4d}/{self.learning.budget}  theta {_fmt(update.theta_before)} -> "
                        f"{_fmt(update.theta_after)}  executed {_fmt(m.proposal.theta)}  "
                        f"cost {update.cost:.4f}  {critic}  kappa {update.kappa:g}{where}")
            return
        self._print(f"episode {m.idx + 1:4d}/{self.learning.budget}  executed {_fmt(m.proposal.theta)}  "
                    f"cost {cost:.4f}{where}")
        self._print(f"update {update.idx + 1:5d}  episodes {members[0].idx + 1}-{members[-1].idx + 1}  "
                    f"theta {_fmt(update.theta_before)} -> {_fmt(update.theta_after)}  cost {update.cost:.4f} "
                    f"(mean)  {critic}  kappa {update.kappa:g}")

    def _commit(self, members: list[_Member], completing: EpisodeResult | None) -> UpdateRecord:
        return self.learning.commit_update([m.proposal for m in members], [m.terms for m in members],
                                           [m.episode_id for m in members], completing)

    def _next_outcome(self) -> Finished:
        """The next finished request; while requests wait and no agent is there, the state is
        ``paused`` (``AgentAbsent`` after ``agent_wait_s``)."""
        absent_since: float | None = None
        single = len(self.config.sources) == 1
        while True:
            done = self.fleet.outcome(0.1, on_new=lambda robot: self._print(f"agent {robot} joined the fleet"))
            if done is not None or not self.fleet.starved():
                if absent_since is not None:
                    self.learning.status = "running"
                    self._print("agent is alive" if single else f"agents alive: {', '.join(self.fleet.ready())}")
                    absent_since = None
                if done is not None:
                    return done
                continue
            now = time.monotonic()
            if absent_since is None:
                absent_since = now
                self.learning.status = "paused"
                what = (f"the agent ({self.keys.agent_alive})" if single
                        else f"an agent of the fleet ({', '.join(self.fleet.patterns)})")
                self._print(f"waiting for {what} ...")
            elif self.config.agent_wait_s is not None and now - absent_since >= self.config.agent_wait_s:
                raise AgentAbsent(f"no agent on {', '.join(self.fleet.patterns)} for {self.config.agent_wait_s:g} s")

    def _publish(self, m: _Member, request: EpisodeRequest, result: EpisodeResult | None,
                 cost: float | None) -> None:
        if result is None or self.control is None:
            return
        try:
            self.control.publish_episode(LearnerEpisode(
                self.learning.run_id, m.idx, m.proposal.base_theta, m.proposal.z, request, result, cost,
                time.time()))
        except Exception:  # noqa: BLE001 - a publication must never stop learning
            log.exception("cannot publish episode %s", request.episode_id)
