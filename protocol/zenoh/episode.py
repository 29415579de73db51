"""Episode payloads: the ``episode/run`` query and reply, and the ``episode/done`` publication."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from .codec import (
    ID_PATTERN,
    as_bool,
    as_choice,
    as_float,
    as_float_map,
    as_int,
    as_mapping,
    as_str,
)
from .errors import InvalidField
from .keys import CHUNK_PATTERN
from .messages import Message, set_field
from .tasks import TaskSpec, get_task

__all__ = [
    "SEED_MAX",
    "STATUSES",
    "FAILURE_FLAGS",
    "MAX_DURATION_S",
    "EpisodeRequest",
    "EpisodeResult",
    "EpisodeDone",
]

#: Largest episode seed (seeds are unsigned 32-bit).
SEED_MAX = 2**32 - 1
#: Episode outcomes. Only ``"ok"`` episodes carry a total cost and all cost terms.
STATUSES: tuple[str, ...] = (
    "ok",
    "fault_heartbeat",  # a controller or the agent lost the other's heartbeat
    "fault_pdo_timeout",  # a synchronous TPDO did not arrive in time
    "fault_emcy",  # an EMCY that is not a task outcome (e.g. driver fault)
    "fault_simulator",  # the simulated bench failed (simulation diverged, bench node error)
    "aborted",  # stopped on request
)
#: Task-outcome flags (they are costs/observations, not faults: an "ok" episode may have them).
FAILURE_FLAGS: tuple[str, ...] = ("hardware_damage", "over_current", "fallen", "bottle_dropped")
#: Upper bound on simulated and wall-clock durations in a result (s).
MAX_DURATION_S = 86_400.0


@dataclass(frozen=True)
class EpisodeRequest(Message):
    """Query payload of ``episode/run``: run one episode of ``task`` at ``theta``.

    Attributes:
        episode_id: unique id chosen by the learner (matches :data:`ID_PATTERN`).
        task: a key of ``TASKS``.
        theta: policy parameters, shape ``(TASKS[task].dim,)``, inside the task bounds.
        seed: scenario seed, ``0 <= seed <= 2**32 - 1`` (impact momentum, initial state...).
    """

    TYPE = "episode_request"

    episode_id: str
    task: str
    theta: tuple[float, ...]
    seed: int

    def __post_init__(self) -> None:
        as_str(self.episode_id, "episode_id", pattern=ID_PATTERN)
        set_field(self, "theta", get_task(self.task).check_theta(self.theta))
        set_field(self, "seed", as_int(self.seed, "seed", lo=0, hi=SEED_MAX))

    @property
    def spec(self) -> TaskSpec:
        """The task's :class:`TaskSpec`."""
        return get_task(self.task)


@dataclass(frozen=True)
class EpisodeResult(Message):
    """Reply payload of ``episode/run`` (errors before the episode starts use ``ErrorReply``).

    Attributes:
        episode_id: the request's id.
        task: the request's task.
        status: one of :data:`STATUSES`.
        cost_terms: unweighted cost integrals by name. ``"ok"``: exactly the task's
            ``term_names``; otherwise any subset (integrals up to the fault).
        total_cost: ``TASKS[task].total_cost(cost_terms)`` with the agent's weights (the
            defaults) when ``"ok"``; ``None`` otherwise. Informational: the learner recomputes
            the cost from ``cost_terms`` with its own weights.
        failures: task-outcome flags, keys from :data:`FAILURE_FLAGS`.
        duration_s: simulated (or real) episode time, ``0 <= duration_s <= MAX_DURATION_S``.
        wall_s: wall-clock time the agent spent, same range.
        telemetry: summary figures by snake_case name (``n_cycles``, ``max_abs_pitch`` [rad],
            ``max_abs_pitch_acc`` [rad/s^2], ``energy_j``, ``peak_current_a``...), finite.
        fault_counts: counters by name (``emcy``, ``pdo_timeouts``, ``late_cycles``...), >= 0.
        detail: free text for humans (<= 4096 characters).
    """

    TYPE = "episode_result"

    episode_id: str
    task: str
    status: str
    cost_terms: Mapping[str, float]
    total_cost: float | None
    failures: Mapping[str, bool] = field(default_factory=dict)
    duration_s: float = 0.0
    wall_s: float = 0.0
    telemetry: Mapping[str, float] = field(default_factory=dict)
    fault_counts: Mapping[str, int] = field(default_factory=dict)
    detail: str = ""

    def __post_init__(self) -> None:
        as_str(self.episode_id, "episode_id", pattern=ID_PATTERN)
        spec = get_task(self.task)
        as_choice(self.status, "status", STATUSES)
        ok = self.status == "ok"
        set_field(
            self,
            "cost_terms",
            as_float_map(
                self.cost_terms, "cost_terms",
                names=spec.term_names, required=spec.term_names if ok else (),
            ),
        )
        if ok:
            if self.total_cost is None:
                raise InvalidField("total_cost", "required when status is 'ok'")
            set_field(self, "total_cost", as_float(self.total_cost, "total_cost"))
        elif self.total_cost is not None:
            raise InvalidField("total_cost", f"must be null when status is {self.status!r}")
        set_field(
            self, "failures", as_mapping(self.failures, "failures", as_bool, names=FAILURE_FLAGS)
        )
        set_field(self, "duration_s", as_float(self.duration_s, "duration_s", lo=0.0, hi=MAX_DURATION_S))
        set_field(self, "wall_s", as_float(self.wall_s, "wall_s", lo=0.0, hi=MAX_DURATION_S))
        set_field(self, "telemetry", as_float_map(self.telemetry, "telemetry"))
        set_field(
            self,
            "fault_counts",
            as_mapping(self.fault_counts, "fault_counts", lambda v, f: as_int(v, f, lo=0, hi=2**53)),
        )
        as_str(self.detail, "detail", max_len=4096)

    @property
    def ok(self) -> bool:
        """``status == "ok"``."""
        return self.status == "ok"

    def failed(self, flag: str) -> bool:
        """Whether failure flag ``flag`` is set (absent flags are false)."""
        return bool(self.failures.get(flag, False))


@dataclass(frozen=True)
class EpisodeDone(Message):
    """Publication on ``episode/done``: one finished episode with its request.

    Attributes:
        robot: the robot's key chunk (as in ``KeySpace.robot``).
        stamp_s: UNIX time (s) at which the episode finished.
        request: the request that was run.
        result: its result; ``episode_id`` and ``task`` must match the request's.
    """

    TYPE = "episode_done"
    NESTED = {"request": EpisodeRequest, "result": EpisodeResult}

    robot: str
    stamp_s: float
    request: EpisodeRequest
    result: EpisodeResult

    def __post_init__(self) -> None:
        as_str(self.robot, "robot", pattern=CHUNK_PATTERN)
        set_field(self, "stamp_s", as_float(self.stamp_s, "stamp_s", lo=0.0))
        if not isinstance(self.request, EpisodeRequest):
            raise InvalidField("request", "expected an EpisodeRequest")
        if not isinstance(self.result, EpisodeResult):
            raise InvalidField("result", "expected an EpisodeResult")
        if self.result.episode_id != self.request.episode_id:
            raise InvalidField("result.episode_id", "does not match request.episode_id")
        if self.result.task != self.request.task:
            raise InvalidField("result.task", "does not match request.task")
