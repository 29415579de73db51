"""The control plane's handlers (``control.LearnerHandlers``) on the open run.

Each handler either succeeds completely or raises (``PayloadError`` / ``InvalidField`` for
invalid input, ``ControlError`` for what cannot be served now) having changed nothing.
Everything runs under the run's lock, so a handler never sees half an update.
"""
from __future__ import annotations

from collections.abc import Callable

from protocol.zenoh import (
    STATUSES,
    CriticPoint,
    CriticQuery,
    CriticReply,
    EpisodeRequest,
    EpisodeResult,
    InvalidField,
    KappaCommand,
    LearnerEpisode,
    LearnerState,
    SelectQuery,
    SelectReply,
    WeightsCommand,
    get_task,
)

from .control import ControlError
from .engine import NotEnoughData
from .learning import LearningRun
from .store import EpisodeRecord

__all__ = ["ControlHandlers"]


class ControlHandlers:
    """``state``, ``critic``, ``select`` (optionally adopting), ``set_kappa``, ``set_weights``,
    ``episodes`` (the run's history).

    Args:
        learning: the open run.
        say: prints one progress line (kappa / weights changes).
    """

    def __init__(self, learning: LearningRun, say: Callable[[str], None]) -> None:
        self._run = learning
        self._task = learning.config.task
        self._spec = get_task(self._task)
        self._say = say

    def state(self) -> LearnerState:
        run = self._run
        with run.lock:
            e = run.engine
            return LearnerState(run.run_id, self._task, run.status, e.theta, e.sigma, e.kappa,
                                e.weights, run.n_episodes)

    def critic(self, query: CriticQuery) -> CriticReply:
        points = query.points_for(self._task)
        with self._run.lock:
            engine = self._run.engine
            kappa = engine.kappa if query.kappa is None else query.kappa
            try:
                values = engine.critic(points)
            except NotEnoughData as exc:
                raise ControlError("unavailable", str(exc)) from None
        return CriticReply(self._task, kappa, tuple(
            CriticPoint(p, j, r, j + kappa * r) for p, (j, r) in zip(points, values)))

    def select(self, query: SelectQuery) -> SelectReply:
        spec = self._spec
        with self._run.lock:
            engine = self._run.engine
            weights = dict(engine.weights)
            if query.weights is not None:
                weights.update(query.weights)
            weights = dict(spec.check_weights(weights))
            self._check_finite(weights)
            try:
                theta, j, r = engine.select(query.kappa, weights)
            except NotEnoughData as exc:
                raise ControlError("unavailable", str(exc)) from None
            theta = spec.check_theta(tuple(min(max(t, lo), hi) for t, lo, hi in
                                           zip(theta, spec.lower, spec.upper)))
            if query.adopt:
                self._run.adopt(theta)
        return SelectReply(self._task, theta, j, r, j + query.kappa * r, query.kappa,
                           weights, query.adopt)

    def _check_finite(self, weights: dict[str, float]) -> None:
        try:
            self._run.engine.check_weights(weights)
        except ValueError as exc:
            raise InvalidField("weights", str(exc)) from None

    def set_kappa(self, command: KappaCommand) -> None:
        run = self._run
        with run.lock:
            run.store.record_change(run.run_id, "kappa", command.kappa, "control", run.n_updates)
            run.engine.set_kappa(command.kappa)
        self._say(f"kappa -> {command.kappa:g} (from update {run.n_updates + 1})")

    def set_weights(self, command: WeightsCommand) -> None:
        run = self._run
        with run.lock:
            engine = run.engine
            weights = dict(engine.weights)
            weights.update(command.weights)
            weights = dict(self._spec.check_weights(weights, "weights"))
            self._check_finite(weights)
            current = engine.weights
            engine.set_weights(weights)  # validates against the learner's terms first
            try:
                run.store.record_weights(run.run_id, weights, "control", engine.cost)
            except BaseException:
                engine.set_weights(current)
                raise
        self._say(f"weights -> {weights} ({run.n_updates} stored episodes re-costed)")

    def episodes(self) -> list[LearnerEpisode]:
        """Every attempt of the run the agent answered, in recording order, as it was published
        on ``learner/episodes`` (the cost under the current weights, stamped when recorded)."""
        with self._run.lock:
            records = self._run.store.attempts(self._run.run_id)
        return [_published(record, self._task) for record in records
                if record.status in STATUSES and record.cost_terms is not None]


def _published(record: EpisodeRecord, task: str) -> LearnerEpisode:
    """The ``LearnerEpisode`` of a stored attempt that has the agent's result."""
    request = EpisodeRequest(record.episode_id, task, record.theta, record.seed)
    result = EpisodeResult(record.episode_id, task, record.status, dict(record.cost_terms or {}),
                           record.agent_cost, dict(record.failures or {}), record.duration_s or 0.0,
                           record.wall_s or 0.0, dict(record.telemetry or {}),
                           dict(record.fault_counts or {}), record.detail, record.trace,
                           record.mcap)
    return LearnerEpisode(record.run_id, record.idx, record.base_theta, record.z, request, result,
                          record.cost if record.status == "ok" else None,
                          record.finished_s or record.requested_s)
