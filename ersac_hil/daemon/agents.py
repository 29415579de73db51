"""The learner's link to its agent: presence, one episode query, reply classification.

Presence is the agent's liveliness token (``agent/alive``) AND the reachability of its
``episode/run`` queryable (an agent may announce itself before its queryable's declaration
has propagated). :meth:`AgentLink.run` sends one ``EpisodeRequest`` and classifies whatever
comes back as an :class:`Outcome` (never raises for anything the agent or the network does):

=============  =========================================================================
status         when
=============  =========================================================================
``ok`` / fault the agent's ``EpisodeResult`` (its own status and detail)
``refused``    ``reply_err`` with an ``ErrorReply``: ``code`` is the agent's error code
``timeout``    no reply within ``episode_timeout_s``, or the query ended early without one
``lost``       the query ended early and the agent's liveliness token went with it
``bad_reply``  a payload that does not decode, a result for another episode or task, or
               only replies from a session that is not the agent's (see below)
``interrupted`` :meth:`AgentLink.cancel` (the daemon is stopping)
=============  =========================================================================

A lost agent cancels the running query at once (no wait for the timeout).

Reply source: the agent declares a second liveliness token, ``agent/session/<zid>``, naming
its Zenoh session. The query goes to every ``episode/run`` queryable (target ALL, no
consolidation) and only a reply whose replier is such a session counts; a reply from any
other session (a rogue queryable) is never used, and if no agent reply comes the attempt is
``bad_reply`` naming the foreign session. With TLS and the access control of
``ersac_hil.roles`` a non-agent identity cannot even declare the queryable.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

from .replies import MalformedReply, ReplyRefused, ReplyTimeout, decode_reply

__all__ = ["AgentLink", "Outcome", "AgentAbsent", "Stopped"]

#: How long an early-ended query waits for the agent's liveliness token to disappear.
_LOST_GRACE_S = 1.0


class AgentAbsent(RuntimeError):
    """The agent stayed away longer than the configured wait."""


class Stopped(Exception):
    """The daemon is stopping (its stop event is set)."""


@dataclass(frozen=True)
class Outcome:
    """What one episode query came to (see the module doc for ``status``)."""

    status: str
    result: EpisodeResult | None
    detail: str
    code: str = ""


class AgentLink:
    """Presence of the agent of ``keys`` and its ``episode/run`` querier on ``session``.

    Args:
        session: an open Zenoh session (closed by the caller after :meth:`close`).
        keys: the robot's key space.
        episode_timeout_s: the query timeout of one episode.
        stop: set when the daemon stops; waits and back-offs then raise :class:`Stopped`.
        on_change: called (outside the link's lock) whenever a presence token comes or goes.
    """

    def __init__(self, session: zenoh.Session, keys: KeySpace, episode_timeout_s: float,
                 stop: threading.Event, on_change: Callable[[], None] | None = None) -> None:
        self.keys = keys
        self.timeout_s = episode_timeout_s
        self._stop = stop
        self._on_change = on_change
        self._agents: set[str] = set()
        self._sessions: set[str] = set()
        self._change = threading.Condition()
        self._token: zenoh.CancellationToken | None = None
        self._liveliness = session.liveliness().declare_subscriber(
            keys.agent_alive, self._on_alive, history=True)
        self._session_tokens = session.liveliness().declare_subscriber(
            keys.agent_sessions, self._on_session, history=True)
        self._querier = session.declare_querier(
            keys.episode_run, timeout=episode_timeout_s, target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE)

    def close(self) -> None:
        for entity in (self._querier, self._session_tokens, self._liveliness):
            entity.undeclare()

    # ------------------------------------------------------------------ presence
    def _on_alive(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._change:
            if sample.kind == zenoh.SampleKind.PUT:
                self._agents.add(key)
            else:
                self._agents.discard(key)
                token = self._token
                if token is not None and not self._agents:
                    token.cancel()  # the episode's agent vanished: do not wait for the timeout
            self._change.notify_all()
        if self._on_change is not None:
            self._on_change()

    def _on_session(self, sample: zenoh.Sample) -> None:
        zid = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._change:
            if sample.kind == zenoh.SampleKind.PUT:
                self._sessions.add(zid)
            else:
                self._sessions.discard(zid)
            self._change.notify_all()
        if self._on_change is not None:
            self._on_change()

    @property
    def alive(self) -> bool:
        """The agent's liveliness token is present."""
        return bool(self._agents)

    def ready(self) -> bool:
        """Tokens present (presence and session) and the ``episode/run`` queryable reachable."""
        return bool(self._agents) and bool(self._sessions) and self._querier.matching_status.matching

    def wait_ready(self, wait_s: float | None) -> None:
        """Block until :meth:`ready`; raises :class:`AgentAbsent` after ``wait_s`` (``None``:
        forever) and :class:`Stopped` when the daemon stops."""
        deadline = None if wait_s is None else time.monotonic() + wait_s
        with self._change:
            while not self.ready():
                if self._stop.is_set():
                    raise Stopped
                if deadline is not None and time.monotonic() >= deadline:
                    raise AgentAbsent(f"no agent on {self.keys.agent_alive} for {wait_s:g} s")
                self._change.wait(0.2 if not self._agents else 0.01)

    def sleep(self, seconds: float) -> None:
        """Back off, cut short by the agent (re)appearing; raises :class:`Stopped`."""
        present = self.alive
        deadline = time.monotonic() + seconds
        with self._change:
            while not self._stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0 or (not present and self._agents):
                    return
                self._change.wait(min(left, 0.2))
        raise Stopped

    def wake(self) -> None:
        """Cancel the running query and wake every waiter (the daemon is stopping)."""
        token = self._token
        if token is not None:
            token.cancel()
        with self._change:
            self._change.notify_all()

    # ------------------------------------------------------------------ one episode
    def run(self, request: EpisodeRequest) -> Outcome:
        """Query ``episode/run`` with ``request`` and classify the answer."""
        token = zenoh.CancellationToken()
        self._token = token
        if self._stop.is_set():
            token.cancel()
        started = time.monotonic()
        foreign: list[str] = []
        try:
            replies = self._querier.get(payload=request.to_json(), encoding="application/json",
                                        cancellation_token=token)
            reply = self._agent_reply(replies, foreign)
        except zenoh.ZError as exc:
            if not token.is_cancelled:  # e.g. the session is going down
                return Outcome("timeout", None, f"query failed: {exc}")
            reply = None  # cancelled before get() (stop, lost agent): raises instead of ending
        finally:
            self._token = None
        if reply is None and foreign:
            return Outcome("bad_reply", None, f"reply from session {', '.join(foreign)}, which is not "
                                              f"the agent's (no {self.keys.agent_sessions} token)")
        if reply is None:
            return self._no_reply(time.monotonic() - started)
        try:
            result = decode_reply(reply, EpisodeResult)
        except ReplyRefused as exc:
            return Outcome("refused", None, str(exc), exc.error.code)
        except ReplyTimeout as exc:
            return Outcome("timeout", None, f"no reply within {self.timeout_s:g} s ({exc})")
        except MalformedReply as exc:
            return Outcome("bad_reply", None, str(exc))
        if (result.episode_id, result.task) != (request.episode_id, request.task):
            return Outcome("bad_reply", None, f"reply for {result.episode_id}/{result.task}, "
                                              f"asked {request.episode_id}/{request.task}")
        return Outcome(result.status, result, result.detail)

    def _agent_reply(self, replies, foreign: list[str]) -> zenoh.Reply | None:  # noqa: ANN001
        """The first reply from an agent session (or Zenoh's own error, which has no replier);
        the ids of other repliers go to ``foreign``."""
        for reply in replies:
            source = reply.replier_id
            if source is None:
                return reply  # Zenoh's own (timeout) error
            zid = str(source.zid)
            with self._change:
                known = zid in self._sessions
            if known:
                return reply
            foreign.append(zid)
        return None

    def _no_reply(self, elapsed: float) -> Outcome:
        if self._stop.is_set():
            return Outcome("interrupted", None, "daemon stopped during the episode")
        if elapsed < self.timeout_s:
            # the query ended early: the queryable went away. Its liveliness token goes
            # with it, a few milliseconds later (another message on the same link).
            with self._change:
                self._change.wait_for(lambda: not self._agents, timeout=_LOST_GRACE_S)
        if not self.alive:
            return Outcome("lost", None, f"the agent vanished after {elapsed:.1f} s of the episode")
        if elapsed < self.timeout_s:
            return Outcome("timeout", None, f"the query ended without a reply after {elapsed:.1f} s")
        return Outcome("timeout", None, f"no reply within {self.timeout_s:g} s")
