"""Zenoh clients of the learner's control plane, for people (CLI) and programs (tests, demo).

Each client is a Zenoh *client* session connected to explicit loopback endpoints. Queries
return the typed reply or raise :class:`RequestRefused` (the learner's ``ErrorReply``) /
:class:`NoAnswer`. Puts (kappa, weights) are confirmed by polling ``learner/state`` until the
new value shows, while listening on ``learner/error`` for a refusal.

A client knows the role of the identity it runs as (the common name of the certificate of its
``--zenoh-config``, ``ersac_hil.certs.role_of_config``) and refuses at once what that role may
not do (:class:`NotPermitted`, "observer may not set kappa": ``ersac_hil.roles.permitted``,
the router's own rules). A query the router drops anyway ends at once without a reply, like
one nobody serves: when ``learner/state`` answers, the client says "not permitted" rather
than "no answer".
"""
from __future__ import annotations

import math
import queue
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import TypeVar

import zenoh

from ersac_hil.certs import CertError, role_of_config
from ersac_hil.roles import parse_identity, permitted
from ersac_hil.zenoh_session import ZenohOptions, open_session, resolve_config
from protocol.zenoh import (
    CriticQuery,
    CriticReply,
    ErrorReply,
    KappaCommand,
    KeySpace,
    LearnerEpisode,
    LearnerState,
    Message,
    PayloadError,
    SelectQuery,
    SelectReply,
    WeightsCommand,
)

from .replies import MalformedReply, ReplyRefused, ReplyTimeout, decode_reply

__all__ = ["ClientError", "RequestRefused", "NoAnswer", "NotPermitted", "LearnerClient", "ACTIONS",
           "identity_role", "check_permitted"]

_M = TypeVar("_M", bound=Message)

#: What a client does -> (the Zenoh message it sends, its key under <prefix>/<robot>/, how a
#: refusal names it).
ACTIONS: dict[str, tuple[str, str, str]] = {
    "state": ("query", "learner/state", "read the learner's state"),
    "critic": ("query", "learner/critic", "query the critic"),
    "select": ("query", "learner/select", "select a policy"),
    "episodes": ("query", "learner/episodes", "read the run's history"),
    "kappa": ("put", "learner/kappa", "set kappa"),
    "weights": ("put", "learner/weights", "set the weights"),
    # a requester of episodes (reproduce --agents, bench/bracing_sweep.py --agents), not a control-plane client
    "run": ("query", "episode/run", "request episodes"),
}


class ClientError(RuntimeError):
    """A control-plane request that did not succeed."""


class RequestRefused(ClientError):
    """The learner refused the request; ``error`` is its ``ErrorReply``."""

    def __init__(self, error: ErrorReply) -> None:
        super().__init__(f"{error.code}: {error.reason}")
        self.error = error


class NoAnswer(ClientError):
    """No learner answered in time (not running, wrong robot name or endpoint)."""


class NotPermitted(ClientError):
    """The identity the client runs as may not do this: its role says so (refused before
    anything is sent), or the router dropped the request."""


def identity_role(options: ZenohOptions) -> str | None:
    """The role of the identity ``options`` connect as (``None``: no certificate, a name that
    is no ersac-hil identity, or a config that cannot be read - opening the session says why)."""
    if not options.config_file:
        return None
    try:
        name = role_of_config(options.config_file)
        return None if name is None else parse_identity(name)[0]
    except (CertError, ValueError):
        return None


def check_permitted(role: str | None, action: str) -> None:
    """Raise :class:`NotPermitted` ("observer may not set kappa") if ``role`` may not do
    ``action`` (a key of :data:`ACTIONS`); an unknown role (``None``) is not checked."""
    message, suffix, what = ACTIONS[action]
    if role is not None and not permitted(role, message, suffix):
        raise NotPermitted(f"{role} may not {what} (its certificate's role; the router would drop "
                           f"the {message} on {suffix})")


class LearnerClient:
    """A control-plane client for one robot.

    Args:
        keys: the robot's key space.
        endpoints: Zenoh endpoints to connect to, or the command line's ``ZenohOptions``
            (endpoints, json5 config file with the certificates of a role, insecure).
        timeout_s: per-request timeout.
        check_role: refuse at once what the identity's role may not do (``role``: the role,
            ``None`` when unknown); off, such a request goes out and the router drops it.
    """

    def __init__(self, keys: KeySpace, endpoints: Sequence[str] | ZenohOptions,
                 timeout_s: float = 10.0, check_role: bool = True) -> None:
        self.keys = keys
        self.timeout_s = timeout_s
        options = endpoints if isinstance(endpoints, ZenohOptions) else ZenohOptions(tuple(endpoints))
        self.role = identity_role(options)
        self._check_role = check_role
        self._session = open_session(resolve_config(options), insecure=options.insecure)

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> LearnerClient:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ queries
    def _replies(self, key: str, parameters: str, cls: type[_M], timeout: float,
                 consolidation: zenoh.ConsolidationMode | None = None) -> Iterator[_M]:
        selector = KeySpace.selector(key, parameters or None)
        for reply in self._session.get(selector, timeout=timeout, consolidation=consolidation):
            try:
                yield decode_reply(reply, cls)
            except ReplyRefused as exc:
                raise RequestRefused(exc.error) from None
            except ReplyTimeout:
                raise NoAnswer(f"no answer on {key} within {timeout:g} s") from None
            except MalformedReply as exc:
                raise ClientError(f"bad reply from {key}: {exc}") from None

    def _may(self, action: str) -> None:
        if self._check_role:
            check_permitted(self.role, action)

    def _get(self, key: str, parameters: str, cls: type[_M], timeout_s: float | None = None) -> _M:
        timeout = self.timeout_s if timeout_s is None else timeout_s
        started = time.monotonic()
        for message in self._replies(key, parameters, cls, timeout):
            return message
        if time.monotonic() - started < timeout / 2:  # ended at once: nothing serves it, or dropped
            if key != self.keys.learner_state and self._learner_answers(timeout):
                raise NotPermitted(f"not permitted: the router dropped the query on {key} (the learner "
                                   f"answers {self.keys.learner_state}; this identity may not ask it)")
            raise NoAnswer(f"no learner answered on {key} (nothing serves it: is the daemon running "
                           "for this robot and endpoint?)")
        raise NoAnswer(f"no learner answered on {key} within {timeout:g} s "
                       "(is the daemon running for this robot and endpoint?)")

    def _learner_answers(self, timeout: float) -> bool:
        try:
            self._get(self.keys.learner_state, "", LearnerState, timeout)
        except ClientError:
            return False
        return True

    def state(self, timeout_s: float | None = None) -> LearnerState:
        self._may("state")
        return self._get(self.keys.learner_state, "", LearnerState, timeout_s)

    def critic(self, query: CriticQuery) -> CriticReply:
        self._may("critic")
        return self._get(self.keys.learner_critic, query.to_parameters(), CriticReply)

    def select(self, query: SelectQuery) -> SelectReply:
        self._may("select")
        return self._get(self.keys.learner_select, query.to_parameters(), SelectReply)

    def episodes(self) -> list[LearnerEpisode]:
        """The run's history: every episode the learner recorded so far, in recording order
        (``[]`` also when no learner answers: ask :meth:`state` to tell the two apart)."""
        self._may("episodes")
        # every reply has the same key: Zenoh's default consolidation would keep the last only
        return list(self._replies(self.keys.learner_episodes, "", LearnerEpisode, self.timeout_s,
                                  zenoh.ConsolidationMode.NONE))

    # ------------------------------------------------------------------ puts
    def put_raw(self, kind: str, payload: bytes) -> None:
        """Put raw bytes on ``learner/<kind>`` (``kappa`` or ``weights``), unchecked."""
        key = {"kappa": self.keys.learner_kappa, "weights": self.keys.learner_weights}[kind]
        self._session.put(key, payload)

    def _put_confirmed(self, kind: str, payload: bytes, done) -> LearnerState:  # noqa: ANN001
        self._may(kind)
        errors: queue.Queue[ErrorReply] = queue.Queue()

        def on_error(sample: zenoh.Sample) -> None:
            try:
                error = ErrorReply.from_json(sample.payload)
            except PayloadError:
                return
            if error.reason.startswith(f"learner/{kind}:"):
                errors.put(error)

        subscriber = self._session.declare_subscriber(self.keys.learner_error, on_error)
        try:
            self.state()  # the learner is there, and our subscriber had time to propagate
            self.put_raw(kind, payload)
            deadline = time.monotonic() + self.timeout_s
            while time.monotonic() < deadline:
                try:
                    raise RequestRefused(errors.get(timeout=0.05))
                except queue.Empty:
                    pass
                state = self.state()
                if done(state):
                    return state
            raise NoAnswer(f"learner/{kind} not applied within {self.timeout_s:g} s although the learner "
                           "answers (a put this identity may not make is dropped by the router unseen)")
        finally:
            subscriber.undeclare()

    def set_kappa(self, kappa: float) -> LearnerState:
        """Put a new kappa and wait until the learner shows it. Raises PayloadError if invalid."""
        command = KappaCommand(kappa)
        return self._put_confirmed("kappa", command.to_json(),
                                   lambda s: math.isclose(s.kappa, command.kappa, rel_tol=0, abs_tol=0))

    def set_weights(self, weights: Mapping[str, float]) -> LearnerState:
        """Put (partial) new weights and wait until the learner shows them."""
        command = WeightsCommand(weights)
        return self._put_confirmed(
            "weights", command.to_json(),
            lambda s: all(s.weights.get(k) == v for k, v in command.weights.items()))
