"""The learner's Zenoh control plane under ``<prefix>/<robot>/learner/``.

=================  ==========  ================================================================
key                kind        semantics
=================  ==========  ================================================================
``state``          queryable   -> ``LearnerState``
``critic``         queryable   ``?theta=a,b|c,d`` or ``?grid=N`` [``;kappa=k``] -> ``CriticReply``
``select``         queryable   ``?kappa=k`` [``;weights=n:v,...``] [``;adopt=true``] -> ``SelectReply``
``kappa``          subscriber  ``KappaCommand``: used from the next update on; recorded
``weights``        subscriber  ``WeightsCommand`` (partial): every stored episode re-costed; recorded
``episodes``       publisher   ``LearnerEpisode`` for every attempt the agent answered
``episodes``       queryable   -> one ``LearnerEpisode`` reply per attempt of the run recorded so
                               far, in recording order: the history a late subscriber missed
``error``          publisher   ``ErrorReply`` for every refused put (reason starts with the key)
=================  ==========  ================================================================

Queries that fail get ``reply_err`` with an ``ErrorReply`` (``invalid_request`` for anything
that does not validate, ``unavailable``/``busy`` from the handlers, ``internal`` for bugs).
Refused puts change nothing; they are logged and published on ``learner/error`` (a put has no
reply channel). Nothing is decoded on Zenoh's own threads: callbacks only enqueue, and one
worker thread handles requests in arrival order, so a put followed by a query from the same
client is seen in that order.
"""
from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any, Protocol

import zenoh

from protocol.zenoh import (
    CriticQuery,
    CriticReply,
    ErrorReply,
    KappaCommand,
    KeySpace,
    LearnerEpisode,
    LearnerState,
    PayloadError,
    SelectQuery,
    SelectReply,
    WeightsCommand,
)
from protocol.zenoh.codec import parse_parameters

__all__ = ["ControlError", "LearnerHandlers", "ControlPlane"]

log = logging.getLogger(__name__)


class ControlError(Exception):
    """A valid request the learner cannot serve now; ``code`` is an ``ErrorReply`` code."""

    def __init__(self, code: str, reason: str) -> None:
        super().__init__(reason)
        self.code = code


class LearnerHandlers(Protocol):
    """What the control plane asks of the daemon. Each method either succeeds completely or
    raises (``PayloadError`` for invalid input, ``ControlError`` otherwise) having changed
    nothing."""

    def state(self) -> LearnerState: ...
    def critic(self, query: CriticQuery) -> CriticReply: ...
    def select(self, query: SelectQuery) -> SelectReply: ...
    def set_kappa(self, command: KappaCommand) -> None: ...
    def set_weights(self, command: WeightsCommand) -> None: ...
    def episodes(self) -> Sequence[LearnerEpisode]: ...


@dataclass(frozen=True)
class _Job:
    kind: str
    item: Any  # zenoh.Query or the payload bytes of a put


class ControlPlane:
    """Declares the control-plane entities on ``session`` and serves them from one worker.

    Args:
        session: an open Zenoh session (the caller closes it after :meth:`close`).
        keys: the robot's key space.
        handlers: the daemon side (see :class:`LearnerHandlers`).
    """

    _QUERIES = ("state", "critic", "select", "episodes")
    _PUTS = ("kappa", "weights")

    def __init__(self, session: zenoh.Session, keys: KeySpace, handlers: LearnerHandlers) -> None:
        self.keys = keys
        self._handlers = handlers
        self._jobs: queue.Queue[_Job | None] = queue.Queue(maxsize=1024)
        self._entities: list[Any] = []
        self._episodes_pub = session.declare_publisher(keys.learner_episodes)
        self._error_pub = session.declare_publisher(keys.learner_error)
        self._entities += [self._episodes_pub, self._error_pub]
        query_keys = {"state": keys.learner_state, "critic": keys.learner_critic,
                      "select": keys.learner_select, "episodes": keys.learner_episodes}
        for kind, key in query_keys.items():
            self._entities.append(session.declare_queryable(key, self._on_query(kind)))
        for kind, key in {"kappa": keys.learner_kappa, "weights": keys.learner_weights}.items():
            self._entities.append(session.declare_subscriber(key, self._on_put(kind)))
        self._worker = threading.Thread(target=self._run, name="learner-control", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------ zenoh callbacks
    def _on_query(self, kind: str):
        def callback(query: zenoh.Query) -> None:
            try:
                self._jobs.put_nowait(_Job(kind, query))
            except queue.Full:
                query.reply_err(ErrorReply("busy", "control plane queue full; retry").to_json())
                query.drop()
        return callback

    def _on_put(self, kind: str):
        def callback(sample: zenoh.Sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:
                self._refuse(kind, ErrorReply("invalid_request", "delete is not a command"))
                return
            try:
                self._jobs.put_nowait(_Job(kind, sample.payload.to_bytes()))
            except queue.Full:
                self._refuse(kind, ErrorReply("busy", "control plane queue full; retry"))
        return callback

    # ------------------------------------------------------------------ worker
    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            if job.kind == "__marker__":
                job.item.set()
                continue
            try:
                if job.kind in self._QUERIES:
                    self._serve_query(job.kind, job.item)
                else:
                    self._serve_put(job.kind, job.item)
            except Exception:  # noqa: BLE001 - the worker must survive anything
                log.exception("control plane: %s failed", job.kind)

    def _serve_query(self, kind: str, query: zenoh.Query) -> None:
        with query:
            try:
                replies = self._answer(kind, query)
            except PayloadError as exc:
                error = ErrorReply.from_exception(exc, "invalid_request")
            except ControlError as exc:
                error = ErrorReply(exc.code, str(exc) or exc.code)
            except Exception as exc:  # noqa: BLE001
                log.exception("learner/%s query failed", kind)
                error = ErrorReply("internal", f"{type(exc).__name__}: {exc}"[:4096])
            else:
                for reply in replies:
                    query.reply(query.key_expr, reply.to_json(), encoding="application/json")
                return
            log.info("refused learner/%s?%s: %s", kind, str(query.parameters)[:200], error.reason)
            query.reply_err(error.to_json(), encoding="application/json")

    def _answer(self, kind: str, query: zenoh.Query) -> Sequence[Any]:
        """The replies to one query (one message, or one per episode of the history)."""
        payload = query.payload
        if payload is not None and len(payload.to_bytes()) > 0:
            raise ControlError("invalid_request", f"learner/{kind} takes no payload; use selector parameters")
        if kind in ("state", "episodes"):
            parse_parameters(query.parameters, ())  # none accepted: unknown ones are refused
            return [self._handlers.state()] if kind == "state" else self._handlers.episodes()
        if kind == "critic":
            return [self._handlers.critic(CriticQuery.from_parameters(query.parameters))]
        return [self._handlers.select(SelectQuery.from_parameters(query.parameters))]

    def _serve_put(self, kind: str, payload: bytes) -> None:
        try:
            if kind == "kappa":
                self._handlers.set_kappa(KappaCommand.from_json(payload))
            else:
                self._handlers.set_weights(WeightsCommand.from_json(payload))
        except PayloadError as exc:
            self._refuse(kind, ErrorReply.from_exception(exc, "invalid_request"))
        except ControlError as exc:
            self._refuse(kind, ErrorReply(exc.code, str(exc) or exc.code))
        except Exception as exc:  # noqa: BLE001
            log.exception("learner/%s put failed", kind)
            self._refuse(kind, ErrorReply("internal", f"{type(exc).__name__}: {exc}"))

    def _refuse(self, kind: str, error: ErrorReply) -> None:
        reason = f"learner/{kind}: {error.reason}"[:4096]
        log.warning("refused put on %s/learner/%s: %s", self.keys.root, kind, error.reason)
        self._error_pub.put(ErrorReply(error.code, reason).to_json(), encoding="application/json")

    # ------------------------------------------------------------------ publications
    def publish_episode(self, episode: LearnerEpisode) -> None:
        """Publish one recorded attempt on ``learner/episodes``."""
        self._episodes_pub.put(episode.to_json(), encoding="application/json")

    def drain(self, timeout_s: float = 5.0) -> None:
        """Wait until every queued request was handled (tests, orderly shutdown)."""
        done = threading.Event()
        self._jobs.put(_Job("__marker__", done))
        done.wait(timeout_s)

    def close(self) -> None:
        """Undeclare everything and stop the worker (pending queries get ``unavailable``)."""
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - session may already be closed
                pass
        self._entities.clear()
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None and isinstance(job.item, zenoh.Query):
                with job.item as query:
                    query.reply_err(ErrorReply("unavailable", "learner shutting down").to_json())
        self._jobs.put(None)
        self._worker.join(timeout=10.0)
