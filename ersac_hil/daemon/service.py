"""The learner daemon: ERSAC driven against the agent's ``episode/run``, one episode at a time.

Lifecycle (``ersac_hil.lifecycle.serve``): ``start()`` opens the store, opens or resumes the
run, rebuilds the learner, connects to Zenoh, declares the control plane and starts the
learning thread; ``stop()`` cancels an in-flight query (the attempt is recorded
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
from dataclasses import dataclass
from typing import TextIO

import zenoh

from ersac_hil.zenoh_session import make_config, open_session
from protocol.zenoh import (
    CriticPoint,
    CriticQuery,
    CriticReply,
    EpisodeRequest,
    EpisodeResult,
    ErrorReply,
    InvalidField,
    KappaCommand,
    LearnerEpisode,
    LearnerState,
    PayloadError,
    SelectQuery,
    SelectReply,
    WeightsCommand,
    get_task,
)

from .config import DaemonConfig
from .control import ControlError, ControlPlane
from .engine import NotEnoughData, Proposal, Step
from .runs import episode_id, open_run, rebuild_engine, scenario_seed
from .store import Store, UpdateRecord

__all__ = ["Daemon", "RunFailed", "EXIT_FAILED", "EXIT_NO_AGENT", "MAX_REDRAWS"]

log = logging.getLogger(__name__)

#: Exit status when the run failed (too many failed attempts, contract mismatch).
EXIT_FAILED = 3
#: Exit status when the agent stayed absent longer than ``agent_wait_s`` (run resumable).
EXIT_NO_AGENT = 4
#: Perturbations of one episode the agent may refuse (``invalid_request``) before the run fails.
MAX_REDRAWS = 20
#: How long an early-ended query waits for the agent's liveliness token to disappear.
_LOST_GRACE_S = 1.0


class RunFailed(RuntimeError):
    """The run cannot continue; the store marks it failed."""


class _AgentAbsent(RuntimeError):
    """The agent stayed away longer than ``agent_wait_s``."""


class _Stopped(Exception):
    """stop() was called."""


@dataclass(frozen=True)
class _Outcome:
    status: str
    result: EpisodeResult | None
    detail: str
    code: str = ""


def _fmt(values) -> str:  # noqa: ANN001
    vals = [f"{v:.4f}" for v in values]
    return vals[0] if len(vals) == 1 else "[" + ", ".join(vals) + "]"


class Daemon:
    """The learner daemon service (``start``/``stop``) and the control plane's handlers."""

    def __init__(self, config: DaemonConfig, out: TextIO | None = None) -> None:
        self.config = config
        self.keys = config.keys
        self.spec = get_task(config.task)
        self.out = out if out is not None else sys.stdout
        self.finished = threading.Event()
        self.exit_code = 0
        self._stop = threading.Event()
        self._lock = threading.RLock()  # engine + store consistency
        self._agents: set[str] = set()
        self._agent_change = threading.Condition()
        self._token: zenoh.CancellationToken | None = None
        self._proposal_open = False  # between propose() and the commit of its update
        self._pending_adopt: tuple[float, ...] | None = None
        self._status = "idle"
        self.store: Store | None = None
        self.session: zenoh.Session | None = None
        self.control: ControlPlane | None = None
        self._thread: threading.Thread | None = None
        self._liveliness = None
        self._querier: zenoh.Querier | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self.store = Store(self.config.db)
        self.run, self.config, resumed = open_run(self.store, self.config)
        interrupted = self.store.interrupt_pending(self.run.run_id, "daemon died while pending")
        self.engine = rebuild_engine(self.store, self.run)
        self.n_updates = self.store.update_count(self.run.run_id)
        self.session = open_session(make_config("client", connect=list(self.config.zenoh),
                                                connect_timeout_s=10.0))
        self._liveliness = self.session.liveliness().declare_subscriber(
            self.keys.agent_alive, self._on_alive, history=True)
        self._querier = self.session.declare_querier(self.keys.episode_run,
                                                     timeout=self.config.episode_timeout_s)
        self.control = ControlPlane(self.session, self.keys, self)
        budget = self.run.settings["episodes"]
        how = (f"resumed at episode {self.n_updates + 1}" + (f", {interrupted} interrupted attempt(s)"
               if interrupted else "")) if resumed else "new"
        self._print(f"run {self.run.run_id} ({how}): {self.config.task} on {self.config.robot}, "
                    f"kappa {self.engine.kappa:g}, {budget} episodes, seed {self.run.seed}, "
                    f"store {self.config.db}")
        self._thread = threading.Thread(target=self._main, name="learner-loop", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Idempotent; interrupts a waiting or running episode (recorded ``interrupted``)."""
        if self._stop.is_set():
            return
        self._stop.set()
        token = self._token
        if token is not None:
            token.cancel()
        with self._agent_change:
            self._agent_change.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
        if self.control is not None:
            self.control.close()
        for entity in (self._querier, self._liveliness):
            if entity is not None:
                entity.undeclare()
        if self.session is not None:
            self.session.close()
        if self.store is not None:
            self.store.close()

    def _print(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    # ------------------------------------------------------------------ agent presence
    def _on_alive(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._agent_change:
            if sample.kind == zenoh.SampleKind.PUT:
                self._agents.add(key)
            else:
                self._agents.discard(key)
                token = self._token
                if token is not None and not self._agents:
                    token.cancel()  # the episode's agent vanished: do not wait for the timeout
            self._agent_change.notify_all()

    @property
    def agent_alive(self) -> bool:
        return bool(self._agents)

    def _agent_ready(self) -> bool:
        """Liveliness token present AND its ``episode/run`` queryable reachable (an agent may
        announce itself before its queryable's declaration has propagated)."""
        return bool(self._agents) and self._querier.matching_status.matching

    def _wait_for_agent(self) -> None:
        if self._agent_ready():
            return
        self._print(f"waiting for the agent ({self.keys.agent_alive}) ...")
        self._status = "paused"
        deadline = None if self.config.agent_wait_s is None else time.monotonic() + self.config.agent_wait_s
        with self._agent_change:
            while not self._agent_ready():
                if self._stop.is_set():
                    raise _Stopped
                if deadline is not None and time.monotonic() >= deadline:
                    raise _AgentAbsent(f"no agent on {self.keys.agent_alive} for {self.config.agent_wait_s:g} s")
                self._agent_change.wait(0.2 if not self._agents else 0.01)
        self._status = "running"
        self._print("agent is alive")

    def _sleep(self, seconds: float) -> None:
        """Back off, cut short by stop() or by an agent (re)appearing."""
        present = self.agent_alive
        deadline = time.monotonic() + seconds
        with self._agent_change:
            while not self._stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0 or (not present and self._agents):
                    return
                self._agent_change.wait(min(left, 0.2))
        raise _Stopped

    # ------------------------------------------------------------------ learning loop
    def _main(self) -> None:
        try:
            self._status = "running"
            while self.n_updates < self.run.settings["episodes"]:
                if self._stop.is_set():
                    return
                self._learn_one()
            self.store.set_run_status(self.run.run_id, "finished")
            self._status = "idle"
            self._print(f"run {self.run.run_id} finished: {self.n_updates} episodes, "
                        f"theta {_fmt(self.engine.theta)}, kappa {self.engine.kappa:g}")
            if not self.config.linger:
                self.finished.set()
        except _Stopped:
            self._status = "stopped"
        except _AgentAbsent as exc:
            self._print(f"giving up: {exc}; the run stays resumable")
            self.exit_code = EXIT_NO_AGENT
            self._status = "paused"
            self.finished.set()
        except RunFailed as exc:
            self._print(f"run {self.run.run_id} failed: {exc}")
            self.store.set_run_status(self.run.run_id, "failed", str(exc))
            self.exit_code = EXIT_FAILED
            self._status = "failed"
            self.finished.set()
        except Exception as exc:  # noqa: BLE001
            log.exception("learning loop crashed")
            self._print(f"learning loop crashed: {type(exc).__name__}: {exc}")
            self.exit_code = 1
            self._status = "failed"
            self.finished.set()

    def _learn_one(self) -> None:
        idx = self.n_updates
        with self._lock:
            self._apply_pending_adopt()
            proposal = self.engine.propose()
            self._proposal_open = True
        seed = scenario_seed(self.run.seed, idx)
        attempts = self.store.attempts_of(self.run.run_id, idx)
        attempt = attempts[-1].attempt + 1 if attempts else 0
        failures = redraws = 0
        backoff = self.config.backoff_s[0]
        budget = self.run.settings["episodes"]
        while True:
            self._wait_for_agent()
            eid = episode_id(self.run.run_id, idx, attempt)
            request = EpisodeRequest(eid, self.config.task, proposal.theta, seed)
            self.store.begin_attempt(self.run.run_id, eid, idx, attempt, proposal.base_theta,
                                     proposal.z, proposal.theta, seed)
            outcome = self._run_episode(request)
            if outcome.status == "ok":
                step = self._commit_success(idx, request, outcome.result, proposal)
                critic = ("J~ (warm-up)  r~ (warm-up)" if step.warmup
                          else f"J~ {step.J:.4f}  r~ {step.r:.4f}")
                self._print(f"episode {idx + 1:4d}/{budget}  theta {_fmt(step.theta_before)} -> "
                            f"{_fmt(step.theta_after)}  executed {_fmt(proposal.theta)}  "
                            f"cost {step.cost:.4f}  {critic}  kappa {step.kappa:g}")
                return
            self.store.record_failure(eid, outcome.status, outcome.detail, outcome.result)
            self._publish(idx, request, outcome.result, proposal, None)
            if outcome.status == "interrupted":
                raise _Stopped
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
                with self._lock:
                    self.engine.discard()
                    proposal = self.engine.propose()
                self._print(f"episode {idx + 1:4d} attempt {attempt}: refused ({outcome.detail[:200]}) "
                            "- drawing a new perturbation")
                continue
            failures += 1
            if failures >= self.config.max_attempts:
                raise RunFailed(f"episode {idx + 1}: {failures} failed attempts, last {outcome.status}: "
                                f"{outcome.detail}")
            self._print(f"episode {idx + 1:4d} attempt {attempt}: {outcome.status} "
                        f"({outcome.detail[:200]}) - retrying in {backoff:g} s")
            self._sleep(backoff)
            backoff = min(2 * backoff, self.config.backoff_s[1])

    def _run_episode(self, request: EpisodeRequest) -> _Outcome:
        timeout = self.config.episode_timeout_s
        token = zenoh.CancellationToken()
        self._token = token
        if self._stop.is_set():
            token.cancel()
        started = time.monotonic()
        try:
            replies = self._querier.get(payload=request.to_json(), encoding="application/json",
                                        cancellation_token=token)
            reply = next(iter(replies), None)
        except zenoh.ZError as exc:
            if not token.is_cancelled:  # e.g. the session is going down
                return _Outcome("timeout", None, f"query failed: {exc}")
            reply = None  # cancelled before get() (stop, lost agent): raises instead of ending
        finally:
            self._token = None
        if reply is None:
            elapsed = time.monotonic() - started
            if self._stop.is_set():
                return _Outcome("interrupted", None, "daemon stopped during the episode")
            if elapsed < timeout:
                # the query ended early: the queryable went away. Its liveliness token goes
                # with it, a few milliseconds later (another message on the same link).
                with self._agent_change:
                    self._agent_change.wait_for(lambda: not self._agents, timeout=_LOST_GRACE_S)
            if not self.agent_alive:
                return _Outcome("lost", None, f"the agent vanished after {elapsed:.1f} s of the episode")
            if elapsed < timeout:
                return _Outcome("timeout", None, f"the query ended without a reply after {elapsed:.1f} s")
            return _Outcome("timeout", None, f"no reply within {timeout:g} s")
        if reply.ok is None:
            raw = reply.err.payload.to_bytes()
            try:
                error = ErrorReply.from_json(raw)
            except PayloadError:
                text = raw.decode("utf-8", "replace")[:500]
                if "timeout" in text.lower():
                    return _Outcome("timeout", None, f"no reply within {timeout:g} s ({text})")
                return _Outcome("bad_reply", None, f"reply_err without an ErrorReply: {text!r}")
            return _Outcome("refused", None, f"{error.code}: {error.reason}", error.code)
        try:
            result = EpisodeResult.from_json(reply.ok.payload)
        except PayloadError as exc:
            return _Outcome("bad_reply", None, f"invalid episode_result: {exc}")
        if (result.episode_id, result.task) != (request.episode_id, request.task):
            return _Outcome("bad_reply", None, f"reply for {result.episode_id}/{result.task}, "
                                               f"asked {request.episode_id}/{request.task}")
        return _Outcome(result.status, result, result.detail)

    def _commit_success(self, idx: int, request: EpisodeRequest, result: EpisodeResult,
                        proposal: Proposal) -> Step:
        with self._lock:
            step = self.engine.learn(proposal, dict(result.cost_terms))
            update = UpdateRecord(self.run.run_id, idx, request.episode_id, step.theta_before,
                                  step.theta_after, step.cost, step.J, step.r, step.r_z,
                                  step.td_error, step.kappa, step.lr, self.engine.snapshot(),
                                  time.time())
            self.store.record_success(request.episode_id, result, step.cost, update)
            self.n_updates = idx + 1
            self._proposal_open = False
            self._apply_pending_adopt()
        self._publish(idx, request, result, proposal, step.cost)
        return step

    def _publish(self, idx: int, request: EpisodeRequest, result: EpisodeResult | None,
                 proposal: Proposal, cost: float | None) -> None:
        if result is None or self.control is None:
            return
        try:
            self.control.publish_episode(LearnerEpisode(
                self.run.run_id, idx, proposal.base_theta, proposal.z, request, result, cost, time.time()))
        except Exception:  # noqa: BLE001 - a publication must never stop learning
            log.exception("cannot publish episode %s", request.episode_id)

    def _apply_pending_adopt(self) -> None:
        theta, self._pending_adopt = self._pending_adopt, None
        if theta is not None:
            self.engine.adopt(theta)
            self.store.record_change(self.run.run_id, "theta", list(theta), "select", self.n_updates)

    # ------------------------------------------------------------------ control plane handlers
    def state(self) -> LearnerState:
        with self._lock:
            return LearnerState(self.run.run_id, self.config.task, self._status, self.engine.theta,
                                self.engine.sigma, self.engine.kappa, self.engine.weights,
                                self.n_updates)

    def critic(self, query: CriticQuery) -> CriticReply:
        points = query.points_for(self.config.task)
        with self._lock:
            kappa = self.engine.kappa if query.kappa is None else query.kappa
            try:
                values = self.engine.critic(points)
            except NotEnoughData as exc:
                raise ControlError("unavailable", str(exc)) from None
        return CriticReply(self.config.task, kappa, tuple(
            CriticPoint(p, j, r, j + kappa * r) for p, (j, r) in zip(points, values)))

    def select(self, query: SelectQuery) -> SelectReply:
        with self._lock:
            weights = dict(self.engine.weights)
            if query.weights is not None:
                weights.update(query.weights)
            weights = dict(self.spec.check_weights(weights))
            self._check_finite(weights)
            try:
                theta, j, r = self.engine.select(query.kappa, weights)
            except NotEnoughData as exc:
                raise ControlError("unavailable", str(exc)) from None
            theta = self.spec.check_theta(tuple(min(max(t, lo), hi) for t, lo, hi in
                                                zip(theta, self.spec.lower, self.spec.upper)))
            if query.adopt:
                self._pending_adopt = theta
                if not self._proposal_open:
                    self._apply_pending_adopt()
        return SelectReply(self.config.task, theta, j, r, j + query.kappa * r, query.kappa,
                           weights, query.adopt)

    def _check_finite(self, weights: dict[str, float]) -> None:
        try:
            self.engine.check_weights(weights)
        except ValueError as exc:
            raise InvalidField("weights", str(exc)) from None

    def set_kappa(self, command: KappaCommand) -> None:
        with self._lock:
            self.store.record_change(self.run.run_id, "kappa", command.kappa, "control", self.n_updates)
            self.engine.set_kappa(command.kappa)
        self._print(f"kappa -> {command.kappa:g} (from update {self.n_updates + 1})")

    def set_weights(self, command: WeightsCommand) -> None:
        with self._lock:
            weights = dict(self.engine.weights)
            weights.update(command.weights)
            weights = dict(self.spec.check_weights(weights, "weights"))
            self._check_finite(weights)
            current = self.engine.weights
            self.engine.set_weights(weights)  # validates against the learner's terms first
            try:
                self.store.record_weights(self.run.run_id, weights, "control", self.engine.cost)
            except BaseException:
                self.engine.set_weights(current)
                raise
        self._print(f"weights -> {weights} ({self.n_updates} stored episodes re-costed)")
