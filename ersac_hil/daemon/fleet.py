"""A fleet of agents behind one learner: episode requests go to whichever agent is free.

Sources are robot names or one-chunk key expressions of names (``ubot2``, ``*``,
``ubot$*``) under one key prefix. A named robot gets its :class:`~.agents.AgentLink` at once;
a pattern is watched with a liveliness subscriber on ``<prefix>/<pattern>/agent/alive`` and
every robot seen there gets one when the fleet is next polled (:meth:`Fleet.outcome`). A link
is never dropped: it keeps tracking its agent's presence (an agent may come back).

Each link has one worker thread. An idle worker whose agent is ready (presence tokens and a
reachable ``episode/run``, see ``AgentLink.ready``) takes the oldest queued request whose
back-off has passed, runs it (``AgentLink.run``: presence, reply source, classification)
and hands back a :class:`Finished`. The idle ready workers are the free list; which agent
runs which request does not matter to the results, because a request carries everything
the episode depends on (theta, the scenario seed). An agent that vanishes mid-episode ends
its query at once (``lost``); the caller decides what to re-send (:meth:`Fleet.submit`), and
the re-sent request goes to any ready agent.

:func:`find_agents` is the start of a command that runs its work on agents already running
behind a router (``reproduce --agents``, ``bench/bracing_sweep.py --agents``): the robots a
source shows now whose agents are ready, or :class:`NoAgents` saying how many answered.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import zenoh

from ersac_hil.zenoh_session import (EndpointError, ZenohConfigError, ZenohOptions, ZenohSessionError, open_session,
                                     resolve_config)
from protocol.zenoh import EpisodeRequest, KeySpace

from .agents import AgentLink, Outcome, Stopped

__all__ = ["Fleet", "Finished", "NoAgents", "find_agents", "reach_agents"]

#: Poll period of idle workers (the querier's matching status has no notification).
_POLL_S = 0.02


@dataclass(frozen=True)
class Finished:
    """One request's outcome and the robot whose agent ran it; ``error``: what the request's
    ``start`` hook raised (then nothing was sent and ``outcome`` is None)."""

    request: EpisodeRequest
    outcome: Outcome | None
    robot: str
    error: Exception | None = None


@dataclass(order=True)
class _Job:
    not_before: float
    seq: int
    request: EpisodeRequest = field(compare=False)
    start: Callable[[], None] | None = field(compare=False, default=None)


class Fleet:
    """Agents of ``sources`` under ``prefix`` on ``session``, one worker per agent.

    Args:
        session: an open Zenoh session (closed by the caller after :meth:`close`).
        prefix: the key prefix of every robot.
        sources: robot names or one-chunk key expressions of names.
        episode_timeout_s: the query timeout of one episode.
        stop: the daemon's stop event: workers end, :meth:`outcome` raises ``Stopped``.
    """

    def __init__(self, session: zenoh.Session, prefix: str, sources: Sequence[str], episode_timeout_s: float,
                 stop: threading.Event) -> None:
        self.prefix, self.sources = prefix, tuple(sources)
        self._session, self._timeout_s, self._stop = session, episode_timeout_s, stop
        self._cond = threading.Condition()
        self._links: dict[str, AgentLink] = {}
        self._workers: list[threading.Thread] = []
        self._seen: set[str] = set()
        self._queue: list[_Job] = []
        self._running: dict[str, EpisodeRequest] = {}
        self._done: deque[Finished] = deque()
        self._seq = 0
        self._closed = False
        self._watchers = []
        for source in self.sources:
            if "*" in source:
                self._watchers.append(session.liveliness().declare_subscriber(
                    f"{prefix}/{source}/agent/alive", self._on_seen, history=True))
            else:
                self._add(source)

    @property
    def patterns(self) -> tuple[str, ...]:
        """The presence keys the fleet watches (for messages)."""
        return tuple(f"{self.prefix}/{s}/agent/alive" for s in self.sources)

    @property
    def robots(self) -> list[str]:
        """The robots with a link so far, in the order they were added."""
        with self._cond:
            return list(self._links)

    def ready(self) -> list[str]:
        """Robots whose agent is ready now (busy or not)."""
        return [name for name, link in list(self._links.items()) if link.ready()]

    # ------------------------------------------------------------------ links and workers
    def _on_seen(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        robot = _robot_of(str(sample.key_expr), self.prefix)
        with self._cond:
            self._seen.add(robot)
            self._cond.notify_all()

    def _discover(self) -> list[str]:
        """Links for the robots a pattern has shown (declared here, never in a Zenoh callback)."""
        with self._cond:
            new = sorted(self._seen - set(self._links))
            self._seen.clear()
        added = []
        for robot in new:
            if not _is_robot(robot, self.prefix):
                continue  # a key the pattern matched that is no robot of ours
            self._add(robot)
            added.append(robot)
        return added

    def _add(self, robot: str) -> None:
        link = AgentLink(self._session, KeySpace(robot, self.prefix), self._timeout_s, self._stop,
                         on_change=self._notify)
        worker = threading.Thread(target=self._work, args=(robot, link), name=f"agent-{robot}", daemon=True)
        with self._cond:
            self._links[robot] = link
            self._workers.append(worker)
        worker.start()

    def _notify(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def _take(self, robot: str, link: AgentLink) -> _Job | None:
        """The next job for ``robot``'s idle worker, waiting until there is one it may run."""
        with self._cond:
            while not (self._stop.is_set() or self._closed):
                now = time.monotonic()
                due = [j for j in self._queue if j.not_before <= now]
                if due and link.ready():
                    job = min(due)
                    self._queue.remove(job)
                    self._running[robot] = job.request
                    return job
                self._cond.wait(_POLL_S)
            return None

    def _work(self, robot: str, link: AgentLink) -> None:
        while (job := self._take(robot, link)) is not None:
            try:
                if job.start is not None:
                    job.start()
                finished = Finished(job.request, link.run(job.request), robot)
            except Exception as exc:  # noqa: BLE001 - handed to the learner, which raises it
                finished = Finished(job.request, None, robot, exc)
            with self._cond:
                del self._running[robot]
                self._done.append(finished)
                self._cond.notify_all()

    # ------------------------------------------------------------------ the learner's side
    def submit(self, request: EpisodeRequest, delay_s: float = 0.0,
               start: Callable[[], None] | None = None) -> None:
        """Queue ``request`` for the first free ready agent, not before ``delay_s`` from now;
        ``start()`` runs on the agent's worker right before the query is sent."""
        with self._cond:
            self._seq += 1
            self._queue.append(_Job(time.monotonic() + delay_s, self._seq, request, start))
            self._cond.notify_all()

    def starved(self) -> bool:
        """Requests are queued and no agent is ready to take them."""
        with self._cond:
            queued = bool(self._queue)
        return queued and not self.ready()

    def outcome(self, timeout_s: float, on_new: Callable[[str], None] | None = None) -> Finished | None:
        """The next finished request, or ``None`` after ``timeout_s``. Robots a pattern has
        shown get their link first (``on_new(robot)`` for each). Raises ``Stopped``."""
        for robot in self._discover():
            if on_new is not None:
                on_new(robot)
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._done:
                if self._stop.is_set():
                    raise Stopped
                left = deadline - time.monotonic()
                if left <= 0 or self._seen:
                    return None
                self._cond.wait(left)
            return self._done.popleft()

    def cancel(self) -> None:
        """Drop the queued requests and end the running ones (each then finishes
        ``interrupted`` when the daemon's stop is set, else as its query ended)."""
        with self._cond:
            self._queue.clear()
            links = list(self._links.values())
        for link in links:
            link.wake()

    def close(self) -> None:
        """End the workers (the daemon's stop event should be set) and undeclare everything."""
        with self._cond:
            self._closed = True
            self._queue.clear()
            self._cond.notify_all()
            links, workers = list(self._links.values()), list(self._workers)
        for link in links:
            link.wake()
        for worker in workers:
            worker.join(timeout=10.0)
        for watcher in self._watchers:
            watcher.undeclare()
        for link in links:
            link.close()


# ---------------------------------------------------------------------- agents behind a router
class NoAgents(RuntimeError):
    """No agent of a source is usable, in one line: none answered within the wait, those that
    answered take no episode from this identity, its role may not request episodes, or its
    Zenoh configuration or session does not work."""


def _robot_of(key: str, prefix: str) -> str:
    """The robot chunk of ``<prefix>/<robot>/agent/alive``."""
    return key[len(prefix) + 1: -len("/agent/alive")]


def _is_robot(robot: str, prefix: str) -> bool:
    try:
        KeySpace(robot, prefix)
    except ValueError:
        return False
    return True


def _alive(session: zenoh.Session, key: str, prefix: str, timeout_s: float) -> list[str]:
    """The robots (sorted) whose ``agent/alive`` token on ``key`` the router knows of now."""
    robots = set()
    for reply in session.liveliness().get(key, timeout=max(timeout_s, 0.1)):
        if reply.ok is not None:
            robot = _robot_of(str(reply.ok.key_expr), prefix)
            if _is_robot(robot, prefix):
                robots.add(robot)
    return sorted(robots)


def find_agents(session: zenoh.Session, prefix: str, source: str, wait_s: float,
                stop: threading.Event) -> list[str]:
    """The robots (sorted) whose agents answer ``<prefix>/<source>/agent/alive`` and are ready
    (``AgentLink.ready``: presence, session and a reachable ``episode/run``) within ``wait_s``:
    every agent the router knows of as soon as all of them are ready, else at ``wait_s`` those
    that are. Raises :class:`NoAgents` (none ready: the message says how many answered) or
    ``Stopped``."""
    key = f"{prefix}/{source}/agent/alive"
    deadline = time.monotonic() + wait_s
    links: dict[str, AgentLink] = {}
    try:
        while True:
            if stop.is_set():
                raise Stopped
            for robot in _alive(session, key, prefix, min(deadline - time.monotonic(), 5.0)):
                if robot not in links:
                    links[robot] = AgentLink(session, KeySpace(robot, prefix), 1.0, stop)
            ready = sorted(robot for robot, link in links.items() if link.ready())
            if links and len(ready) == len(links):
                return ready
            if time.monotonic() >= deadline:
                if ready:
                    return ready
                if links:
                    raise NoAgents(
                        f"{len(links)} agent(s) answered on {key} ({', '.join(sorted(links))}) but none takes "
                        f"episode requests from this identity within {wait_s:g} s: not permitted (the router "
                        "routes no episode/run query of it to them), or their episode/run is not up yet")
                others = _alive(session, f"{prefix}/*/agent/alive", prefix, 5.0)
                raise NoAgents(f"no agent answered on {key} within {wait_s:g} s (0 answered; "
                               + (f"agents of other robots under {prefix}/ did: {', '.join(others)})" if others else
                                  f"no agent at all under {prefix}/: is it the router of the pairs?)"))
            stop.wait(0.05)
    finally:
        for link in links.values():
            link.close()


def reach_agents(options: ZenohOptions, source: str, prefix: str, wait_s: float, stop: threading.Event) -> list[str]:
    """:func:`find_agents` through a session opened with ``options`` (``--zenoh``,
    ``--zenoh-config``, ``--insecure``) and closed again. Refused with :class:`NoAgents`, in
    this order: a configuration that cannot be read or used; an identity whose role may not
    request episodes ("not permitted", before anything is sent: ``clients.check_permitted``);
    a session the router refuses or that reaches nothing; no agent ready."""
    from .clients import NotPermitted, check_permitted, identity_role

    try:
        config = resolve_config(options)
        role = identity_role(options)
        check_permitted(role, "run")
        session = open_session(config, insecure=options.insecure)
    except NotPermitted as exc:
        raise NoAgents(f"not permitted: {exc}") from None
    except (ZenohConfigError, EndpointError, ZenohSessionError) as exc:
        raise NoAgents(str(exc)) from None
    try:
        return find_agents(session, prefix, source, wait_s, stop)
    except NoAgents as exc:
        name = _certificate_name(options) if role is None else None
        if name is None:
            raise
        raise NoAgents(f"{exc}; not permitted? this identity, {name!r}, is no role of ersac_hil.roles, and a "
                       "router's access control drops unseen what an identity may not do") from None
    finally:
        session.close()


def _certificate_name(options: ZenohOptions) -> str | None:
    """The common name of the client certificate of ``options``' config file, if any."""
    from ersac_hil.certs import CertError, role_of_config

    try:
        return role_of_config(options.config_file) if options.config_file else None
    except CertError:
        return None
