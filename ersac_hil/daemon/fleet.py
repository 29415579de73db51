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
"""
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import zenoh

from protocol.zenoh import EpisodeRequest, KeySpace

from .agents import AgentLink, Outcome, Stopped
from .discovery import is_robot, robot_of

__all__ = ["Fleet", "Finished"]

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
        robot = robot_of(str(sample.key_expr), self.prefix)
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
            if not is_robot(robot, self.prefix):
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

