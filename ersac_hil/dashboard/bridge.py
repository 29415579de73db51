"""The dashboard's Zenoh side: listens to the control plane, keeps the model, runs controls.

* ``learner/episodes`` subscriber: every publication goes into the model at once and its
  ``episode`` event to the page (the latency path: nothing else happens on it);
* ``learner/error`` subscriber: refusals become notices;
* ``agent/alive`` liveliness subscriber (with history): agent alive or not;
* ``learner/kappa`` and ``learner/weights`` subscribers: a change by anyone (CLI, another
  dashboard) triggers a state refresh;
* the run's history (a ``learner/episodes`` query) once the learner answers a state query:
  when the dashboard starts, after the learner was unreachable, and when a new run starts;
  the episodes subscriber is declared first, so every episode is in the history, live, or
  both (the model draws it once);
* a refresher thread queries ``learner/state`` when woken (after every episode, refusal,
  put or control) and every ``state_period_s`` (an adopt by another client has no
  publication), then the critic (:func:`~ersac_hil.dashboard.model.critic_query`) whenever
  what it depends on changed. Requests coalesce: a burst of episodes costs one refresh.

Controls (:meth:`Bridge.set_kappa` ...) block until the learner confirms (the CLI's
:class:`~ersac_hil.daemon.clients.LearnerClient`); the server runs them in worker threads.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import zenoh

from ersac_hil.daemon.clients import ClientError, LearnerClient, RequestRefused
from ersac_hil.zenoh_session import ZenohOptions, open_session, resolve_config
from protocol.zenoh import (
    ErrorReply,
    KappaCommand,
    KeySpace,
    LearnerEpisode,
    LearnerState,
    PayloadError,
    SelectQuery,
    SelectReply,
    WeightsCommand,
    get_task,
)

from .model import DEFAULT_CRITIC_POINTS, DashboardModel, Event, critic_query

__all__ = ["Bridge"]

log = logging.getLogger(__name__)


class Bridge:
    """Zenoh client of one robot's control plane feeding a :class:`DashboardModel`.

    Args:
        keys: the robot's key space.
        zenoh_options: the command line's Zenoh options (endpoints, json5 config with the identity of a
            role, insecure); both sessions of the bridge use them.
        model: the model to keep (the bridge owns it from now on; read it under :attr:`lock`).
        emit: called with every model event, under :attr:`lock` (so in ``seq`` order); must not block.
        critic_points: points per parameter of the critic view.
        state_period_s: state refresh period when nothing happens.
        timeout_s: per-request timeout of queries and confirmations.
    """

    def __init__(self, keys: KeySpace, zenoh_options: ZenohOptions, model: DashboardModel,
                 emit: Callable[[Event], None], *, critic_points: int = DEFAULT_CRITIC_POINTS,
                 state_period_s: float = 2.0, timeout_s: float = 10.0) -> None:
        self.keys = keys
        self.model = model
        self.lock = threading.Lock()
        self._emit = emit
        self._critic_points = critic_points
        self._period = state_period_s
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._client = LearnerClient(keys, zenoh_options, timeout_s)
        self._session: zenoh.Session | None = None
        self._entities: list = []
        self._thread: threading.Thread | None = None
        self._critic_key: object = None
        self._history_run: str | None = None  # the run whose history the model holds
        try:
            self._session = open_session(resolve_config(zenoh_options), insecure=zenoh_options.insecure)
            s = self._session
            self._entities = [
                s.declare_subscriber(keys.learner_episodes, self._on_episode),
                s.declare_subscriber(keys.learner_error, self._on_error),
                s.declare_subscriber(keys.learner_kappa, lambda _sample: self.refresh()),
                s.declare_subscriber(keys.learner_weights, lambda _sample: self.refresh()),
                s.liveliness().declare_subscriber(keys.agent_alive, self._on_alive, history=True),
            ]
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Bridge:
        self._thread = threading.Thread(target=self._refresher, name="dashboard-refresh", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Idempotent: stop the refresher, undeclare, close both sessions."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
        for entity in self._entities:
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - the session may be gone already
                pass
        self._entities.clear()
        if self._session is not None:
            self._session.close()
            self._session = None
        self._client.close()

    def refresh(self) -> None:
        """Ask the refresher for a state (and, if it changed, critic) update now."""
        self._wake.set()

    # ------------------------------------------------------------------ model access
    def _apply(self, change: Callable[[], list[Event]]) -> None:
        with self.lock:
            for event in change():
                self._emit(event)

    def snapshot(self) -> dict:
        with self.lock:
            return self.model.snapshot()

    # ------------------------------------------------------------------ zenoh callbacks
    def _on_episode(self, sample: zenoh.Sample) -> None:
        try:
            episode = LearnerEpisode.from_json(sample.payload)
        except PayloadError as exc:
            self._apply(lambda: self.model.notice("error", f"invalid learner/episodes payload: {exc}"))
            return
        self._apply(lambda: self.model.add_episode(episode))
        self.refresh()

    def _on_error(self, sample: zenoh.Sample) -> None:
        try:
            text = ErrorReply.from_json(sample.payload).reason
        except PayloadError as exc:
            text = f"invalid learner/error payload: {exc}"
        self._apply(lambda: self.model.notice("error", text))
        self.refresh()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        alive = sample.kind == zenoh.SampleKind.PUT
        self._apply(lambda: self.model.set_agent_alive(alive))

    # ------------------------------------------------------------------ refresher
    def _refresher(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self._period)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                self._refresh_once()
            except Exception:  # noqa: BLE001 - the refresher must survive anything
                log.exception("dashboard refresh failed")

    def _refresh_agent(self) -> None:
        """The agent's phase (``agent/state``): waiting for go, stopped..."""
        from protocol.zenoh import AgentState
        phase, detail = None, ""
        for reply in self._session.get(self.keys.agent_state, timeout=2.0):  # type: ignore[union-attr]
            if reply.ok is not None:
                try:
                    state = AgentState.from_json(reply.ok.payload)
                except PayloadError:
                    continue
                phase, detail = state.phase, state.detail
        self._apply(lambda: self.model.set_agent_state(phase, detail))

    def _refresh_once(self) -> None:
        self._refresh_agent()
        try:
            state = self._client.state()
        except ClientError as exc:
            self._history_run = None  # what was published meanwhile may never have reached us
            self._apply(lambda: self.model.learner_unreachable(str(exc)))
            return
        self._apply(lambda: self.model.set_state(state))
        if state.run_id != self._history_run:
            try:
                history = self._client.episodes()
            except ClientError as exc:
                self._apply(lambda: self.model.notice("error", f"no history of run {state.run_id}: {exc}"))
            else:
                self._history_run = state.run_id
                self._apply(lambda: self.model.load_history(state.run_id, history))
        with self.lock:
            key = self.model.critic_key()
        if key == self._critic_key or self._stop.is_set():
            return
        self._critic_key = key
        spec = get_task(state.task)
        try:
            reply = self._client.critic(critic_query(spec, state.theta, self._critic_points))
        except RequestRefused as exc:
            self._apply(lambda: self.model.critic_unavailable(exc.error.reason))
            return
        except ClientError as exc:
            self._critic_key = None  # try again at the next refresh
            self._apply(lambda: self.model.critic_unavailable(str(exc)))
            return
        self._apply(lambda: self.model.set_critic(reply, state))

    # ------------------------------------------------------------------ controls (blocking)
    def state(self) -> LearnerState:
        """A fresh ``learner/state`` (raises ``ClientError``)."""
        return self._client.state()

    def set_kappa(self, command: KappaCommand) -> LearnerState:
        try:
            return self._client.set_kappa(command.kappa)
        finally:
            self.refresh()

    def set_weights(self, command: WeightsCommand) -> LearnerState:
        try:
            return self._client.set_weights(command.weights)
        finally:
            self.refresh()

    def select(self, query: SelectQuery) -> SelectReply:
        try:
            return self._client.select(query)
        finally:
            if query.adopt:
                self.refresh()
