"""What the dashboard page shows, built from control-plane messages: pure, no I/O.

:class:`DashboardModel` takes the messages the bridge receives (``LearnerEpisode``
publications, ``LearnerState`` replies, ``CriticReply`` replies, agent liveliness, refusals)
and returns JSON-ready *events* for the page: ``(kind, data)`` pairs, each with a sequence
number ``seq`` so a page that starts from :meth:`DashboardModel.snapshot` can drop the events
the snapshot already contains.

Event kinds (``data`` always holds ``seq``):

=========== =================================================================================
``episode`` one learner episode: ``point`` (see :class:`CurvePoint`)
``curve``   every point again (costs re-computed after a weights change)
``state``   ``state`` (the ``LearnerState`` fields), ``task`` (names and bounds),
            ``learner_note`` (why there is no state), ``means`` (policy mean per update),
            ``kappa_marks``
``critic``  ``critic`` (a :class:`CriticView`) or ``None``, ``critic_note``
``agent``   ``alive``: bool
``fault``   ``last_fault``: text
``notice``  ``level`` (``info``/``error``), ``text``: a refusal on ``learner/error`` etc.
=========== =================================================================================
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

from protocol.zenoh import CriticQuery, CriticReply, LearnerEpisode, LearnerState, TaskSpec, get_task

__all__ = ["CurvePoint", "CriticSlice", "CriticView", "DashboardModel", "Event",
           "critic_query", "critic_view", "DEFAULT_CRITIC_POINTS"]

#: Points per parameter of a critic slice.
DEFAULT_CRITIC_POINTS = 41

Event = tuple[str, dict[str, Any]]


@dataclass(frozen=True)
class CurvePoint:
    """One attempt the learner recorded, as the learning curve plots it.

    Attributes:
        seq: position on the curve (0-based): recording order (the history, then what arrived
            live after it).
        index: the learner's 0-based episode index (failed attempts share the index they retry).
        episode_id, status: from the agent's result.
        cost: cost under the learner's *current* weights, ``None`` unless ``status == "ok"``.
        damage: the episode reported hardware damage.
        theta: executed parameters, shape ``(dim,)``.
        base_theta: policy mean before the perturbation, shape ``(dim,)``.
        stamp_s: the learner's UNIX time of recording.
        detail: the agent's detail text (faults).
    """

    seq: int
    index: int
    episode_id: str
    status: str
    cost: float | None
    damage: bool
    theta: tuple[float, ...]
    base_theta: tuple[float, ...]
    stamp_s: float
    detail: str


@dataclass(frozen=True)
class CriticSlice:
    """The critic along parameter ``param`` through ``theta`` (the other parameters fixed).

    Attributes:
        param: parameter index; ``name`` its name; ``lower``/``upper`` its bounds.
        x: the parameter's values, shape ``(n,)``; ``J``, ``r``, ``F``: the critic there, ``(n,)``.
        at: the current policy mean's value of this parameter.
        obs_x, obs_y: observations: executed value of this parameter and cost, shape ``(m,)``.
    """

    param: int
    name: str
    lower: float
    upper: float
    x: tuple[float, ...]
    J: tuple[float, ...]
    r: tuple[float, ...]
    F: tuple[float, ...]
    at: float
    obs_x: tuple[float, ...]
    obs_y: tuple[float, ...]


@dataclass(frozen=True)
class CriticView:
    """The critic over the task box after an update: one slice per parameter.

    Attributes:
        kappa: the kappa of F~. episode_count: updates when it was computed.
        theta: the policy mean the slices pass through, shape ``(dim,)``.
        slices: ``dim`` slices (1-D: the whole box, the paper's Figure 2).
    """

    kappa: float
    episode_count: int
    theta: tuple[float, ...]
    slices: tuple[CriticSlice, ...]


def critic_query(spec: TaskSpec, theta: Sequence[float], points: int = DEFAULT_CRITIC_POINTS) -> CriticQuery:
    """The critic points of one view: for each parameter, ``points`` values spanning its bounds
    with the other parameters at ``theta``, concatenated in parameter order
    (``dim * points`` points)."""
    theta = spec.check_theta(theta)
    thetas = []
    for i, (lo, hi) in enumerate(zip(spec.lower, spec.upper)):
        for k in range(points):
            p = list(theta)
            p[i] = min(hi, lo + (hi - lo) * k / (points - 1))  # no rounding past the bound
            thetas.append(tuple(p))
    return CriticQuery(tuple(thetas))


def critic_view(spec: TaskSpec, theta: Sequence[float], episode_count: int, reply: CriticReply,
                observations: Sequence[tuple[Sequence[float], float]]) -> CriticView:
    """Split a reply to :func:`critic_query` into slices and attach the observations
    (``(executed theta, cost)`` pairs)."""
    n = len(reply.points) // spec.dim
    if n * spec.dim != len(reply.points) or n < 2:
        raise ValueError(f"{len(reply.points)} critic points do not make {spec.dim} slices")
    slices = []
    for i in range(spec.dim):
        pts = reply.points[i * n:(i + 1) * n]
        slices.append(CriticSlice(
            i, spec.param_names[i], spec.lower[i], spec.upper[i],
            tuple(p.theta[i] for p in pts), tuple(p.J for p in pts), tuple(p.r for p in pts),
            tuple(p.F for p in pts), float(theta[i]),
            tuple(float(t[i]) for t, _ in observations), tuple(float(c) for _, c in observations)))
    return CriticView(reply.kappa, episode_count, tuple(float(t) for t in theta), tuple(slices))


def _fault_text(point: CurvePoint) -> str:
    return (f"episode {point.index + 1} ({point.episode_id}): {point.status}"
            + (f": {point.detail}" if point.detail else ""))


def _state_obj(state: LearnerState) -> dict[str, Any]:
    obj = state.to_obj()
    obj["weights"] = dict(state.weights)
    return obj


class DashboardModel:
    """Everything the page shows, updated message by message (not thread-safe: one owner).

    Args:
        robot: robot name (shown).
        read_only: the page shows no controls.
    """

    def __init__(self, robot: str, read_only: bool = False) -> None:
        self.robot = robot
        self.read_only = read_only
        self.seq = 0
        self.points: list[CurvePoint] = []
        self._results: list[Mapping[str, float]] = []  # cost terms per point, to re-cost
        self._seen: set[str] = set()  # episode ids of the points: history and live overlap
        self.state: LearnerState | None = None
        self.means: dict[int, tuple[float, ...]] = {}  # episode index -> policy mean before it
        self.kappa_marks: list[tuple[int, float]] = []  # (update index it applies from, kappa)
        self.critic: CriticView | None = None
        self.critic_note = "waiting for the learner"
        self.agent_alive: bool | None = None
        self.agent_phase: str | None = None  # AgentState.phase: waiting_for_go, stopped...
        self.agent_detail = ""
        self.last_fault = ""
        self.learner_note = "waiting for the learner"
        self.run_id: str | None = None

    # ------------------------------------------------------------------ helpers
    def _event(self, kind: str, **data: Any) -> Event:
        self.seq += 1
        return kind, {"seq": self.seq, **data}

    @property
    def spec(self) -> TaskSpec | None:
        return get_task(self.state.task) if self.state is not None else None

    def _cost(self, spec: TaskSpec | None, terms: Mapping[str, float], told: float | None) -> float | None:
        if told is None or spec is None or self.state is None:
            return told
        try:
            return spec.total_cost(terms, self.state.weights)
        except ValueError:
            return told

    def observations(self) -> list[tuple[tuple[float, ...], float]]:
        """``(executed theta, cost)`` of every ok episode seen, costs under the current weights."""
        return [(p.theta, p.cost) for p in self.points if p.cost is not None]

    def _reset_run(self, run_id: str) -> None:
        self.run_id = run_id
        self.points.clear()
        self._results.clear()
        self._seen.clear()
        self.means.clear()
        self.kappa_marks.clear()
        self.critic = None

    # ------------------------------------------------------------------ inputs
    def add_episode(self, episode: LearnerEpisode) -> list[Event]:
        """A ``learner/episodes`` publication (none if the history brought it already)."""
        events: list[Event] = []
        if episode.run_id != self.run_id:
            self._reset_run(episode.run_id)
            events.append(self._event("curve", **self.curve()))
        if episode.result.episode_id in self._seen:
            return events
        point = self._append(episode)
        events.append(self._event("episode", point=asdict(point)))
        if not episode.result.ok:
            events.append(self._event("fault", last_fault=self.last_fault))
        return events

    def load_history(self, run_id: str, history: Sequence[LearnerEpisode]) -> list[Event]:
        """The run's episodes recorded before this dashboard listened (a ``learner/episodes``
        query, in recording order). Episodes seen live already are not drawn twice; those seen
        live but not in the history are newer (the learner publishes after recording) and
        follow it."""
        events: list[Event] = []
        if run_id != self.run_id:
            self._reset_run(run_id)
            events.append(self._event("curve", **self.curve()))
        history = [e for e in history if e.run_id == run_id]
        known = {e.result.episode_id for e in history}
        if known <= self._seen:
            return events
        fault = self.last_fault
        live = [(p, terms) for p, terms in zip(self.points, self._results) if p.episode_id not in known]
        self.points, self._results, self._seen = [], [], set()
        for episode in history:
            self._append(episode)
        for p, terms in live:
            self.points.append(replace(p, seq=len(self.points)))
            self._results.append(terms)
            self._seen.add(p.episode_id)
        failed = [p for p in self.points if p.status != "ok"]
        self.last_fault = _fault_text(failed[-1]) if failed else fault
        events.append(self._event("curve", **self.curve()))
        events.append(self._event("state", **self._state_data()))
        if self.last_fault != fault:
            events.append(self._event("fault", last_fault=self.last_fault))
        return events

    def _append(self, episode: LearnerEpisode) -> CurvePoint:
        """One new point of the current run (``last_fault`` set if the attempt failed)."""
        result = episode.result
        spec = get_task(episode.request.task)
        point = CurvePoint(
            len(self.points), episode.index, result.episode_id, result.status,
            self._cost(spec, result.cost_terms, episode.cost),
            bool(result.failures.get("hardware_damage", False)), episode.request.theta,
            episode.base_theta, episode.stamp_s, result.detail)
        self.points.append(point)
        self._results.append(result.cost_terms)
        self._seen.add(result.episode_id)
        self.means[episode.index] = episode.base_theta
        if not result.ok:
            self.last_fault = _fault_text(point)
        return point

    def set_state(self, state: LearnerState) -> list[Event]:
        """A ``learner/state`` reply; returns no event when nothing shown changed."""
        events: list[Event] = []
        old = self.state
        if state.run_id != self.run_id:
            self._reset_run(state.run_id)
            old = None
            events.append(self._event("curve", **self.curve()))
        self.state = state
        had_note, self.learner_note = bool(self.learner_note), ""
        if old is not None and state.kappa != old.kappa:
            self.kappa_marks.append((state.episode_count, state.kappa))
        elif old is None and not self.kappa_marks:
            self.kappa_marks.append((state.episode_count, state.kappa))
        self.means[state.episode_count] = state.theta
        if old is not None and dict(old.weights) != dict(state.weights):
            self._recost()
            events.append(self._event("curve", **self.curve()))
        if old != state or events or had_note:
            events.append(self._event("state", **self._state_data()))
        return events

    def _recost(self) -> None:
        spec = self.spec
        self.points = [p if p.cost is None else replace(p, cost=self._cost(spec, terms, p.cost))
                       for p, terms in zip(self.points, self._results)]

    def critic_key(self) -> tuple[Any, ...] | None:
        """What the critic view depends on; a new critic is worth asking for when it changes."""
        s = self.state
        if s is None:
            return None
        return (s.run_id, s.episode_count, s.theta, s.kappa, tuple(sorted(s.weights.items())))

    def set_critic(self, reply: CriticReply, state: LearnerState) -> list[Event]:
        """A reply to :func:`critic_query` for ``state``'s theta."""
        spec = get_task(state.task)
        self.critic = critic_view(spec, state.theta, state.episode_count, reply, self.observations())
        self.critic_note = ""
        return [self._event("critic", critic=asdict(self.critic), critic_note="")]

    def critic_unavailable(self, reason: str) -> list[Event]:
        """The learner cannot give a critic yet (warm-up) or the query failed."""
        if reason == self.critic_note:
            return []
        self.critic_note = reason
        return [self._event("critic", critic=None if self.critic is None else asdict(self.critic),
                            critic_note=reason)]

    def learner_unreachable(self, reason: str) -> list[Event]:
        """The learner did not answer a state query."""
        if reason == self.learner_note:
            return []
        self.learner_note = reason
        return [self._event("state", **self._state_data())]

    def set_agent_alive(self, alive: bool) -> list[Event]:
        if alive == self.agent_alive:
            return []
        self.agent_alive = alive
        if not alive:
            self.agent_phase, self.agent_detail = None, ""
        return [self._agent_event()]

    def set_agent_state(self, phase: str | None, detail: str = "") -> list[Event]:
        """The agent's ``agent/state`` (``None``: it did not answer): ready, waiting for go,
        running, stopped by an e-stop, uncommissioned."""
        if (phase, detail) == (self.agent_phase, self.agent_detail):
            return []
        self.agent_phase, self.agent_detail = phase, detail
        return [self._agent_event()]

    def _agent_event(self) -> Event:
        return self._event("agent", alive=self.agent_alive, phase=self.agent_phase, detail=self.agent_detail)

    def notice(self, level: str, text: str) -> list[Event]:
        """A message for people: a refused put on ``learner/error``, a payload that did not decode."""
        return [self._event("notice", level=level, text=text)]

    # ------------------------------------------------------------------ views
    def _state_data(self) -> dict[str, Any]:
        spec = self.spec
        return {"state": None if self.state is None else _state_obj(self.state),
                "learner_note": self.learner_note,
                "task": None if spec is None else {
                    "name": spec.name, "params": list(spec.param_names), "lower": list(spec.lower),
                    "upper": list(spec.upper), "terms": list(spec.term_names)},
                "means": [[i, list(t)] for i, t in sorted(self.means.items())],
                "kappa_marks": [list(m) for m in self.kappa_marks]}

    def curve(self) -> dict[str, Any]:
        return {"points": [asdict(p) for p in self.points]}

    def snapshot(self) -> dict[str, Any]:
        """Everything shown, as of event ``seq``."""
        return {
            "seq": self.seq, "robot": self.robot, "read_only": self.read_only,
            **self._state_data(), **self.curve(),
            "critic": None if self.critic is None else asdict(self.critic),
            "critic_note": self.critic_note, "agent_alive": self.agent_alive,
            "agent_phase": self.agent_phase, "agent_detail": self.agent_detail,
            "last_fault": self.last_fault,
        }
