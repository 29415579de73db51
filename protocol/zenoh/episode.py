"""Episode payloads: the ``episode/run`` query and reply, and the ``episode/done`` publication."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from msgspec import Meta

from .errors import InvalidField
from .fields import Count, Finite, Id, Name, NonNegative, Text, anchored
from .keys import CHUNK_PATTERN
from .messages import Message
from .tasks import TaskName, TaskSpec, get_task

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
    "fault_simulator",  # the simulated robot failed (simulation diverged, node error)
    "aborted",  # stopped on request
    "stopped",  # e-stop: every axis put into quick stop; never learnt from
)
#: Task-outcome flags (they are costs/observations, not faults: an "ok" episode may have them).
FAILURE_FLAGS: tuple[str, ...] = ("hardware_damage", "over_current", "fallen", "bottle_dropped")
#: Upper bound on simulated and wall-clock durations in a result (s).
MAX_DURATION_S = 86_400.0


Seed = Annotated[int, Meta(ge=0, le=SEED_MAX)]
Duration = Annotated[float, Meta(ge=0.0, le=MAX_DURATION_S)]
Failures = Annotated[
    dict[Literal[FAILURE_FLAGS], bool],  # type: ignore[valid-type]
    Meta(extra_json_schema={"propertyNames": {"enum": list(FAILURE_FLAGS)}}),
]
#: A trace file name: an episode id plus a python-can log suffix, or empty.
TraceName = Annotated[str, Meta(pattern=r"^$|^[A-Za-z0-9][A-Za-z0-9_.:\-]{0,127}\.(blf|asc)$(?!\n)")]
Robot = Annotated[str, Meta(pattern=anchored(CHUNK_PATTERN))]
#: An MCAP episode file name: an episode id plus ``.mcap``, or empty.
McapName = Annotated[str, Meta(pattern=r"^$|^[A-Za-z0-9][A-Za-z0-9_.:\-]{0,127}\.mcap$(?!\n)")]


class EpisodeRequest(Message, frozen=True):
    """Query payload of ``episode/run``: run one episode of ``task`` at ``theta``.

    Attributes:
        episode_id: unique id chosen by the learner (matches ``ID_PATTERN``).
        task: a key of ``TASKS``.
        theta: policy parameters, shape ``(TASKS[task].dim,)``, inside the task bounds.
        seed: scenario seed, ``0 <= seed <= 2**32 - 1`` (impact momentum, initial state...).
    """

    TYPE: ClassVar[str] = "episode_request"

    episode_id: Id
    task: TaskName
    theta: tuple[Finite, ...]
    seed: Seed

    def _check(self) -> None:
        self.spec.check_theta(self.theta)

    @property
    def spec(self) -> TaskSpec:
        """The task's :class:`TaskSpec`."""
        return get_task(self.task)


class EpisodeResult(Message, frozen=True):
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
        trace: file name (no directory) of the episode's CAN trace the agent wrote
            (``agent --record-can DIR``: ``<episode_id>.blf`` or ``.asc``), ``""`` if none.
            Added after the first revision of v1: optional on the wire (absent = ``""``).
        mcap: file name (no directory) of the episode's MCAP file (``agent --record DIR``:
            ``<episode_id>.mcap``), ``""`` if none. Optional on the wire like ``trace``.
    """

    TYPE: ClassVar[str] = "episode_result"
    WIRE_OPTIONAL: ClassVar[frozenset[str]] = frozenset({"trace", "mcap"})

    episode_id: Id
    task: TaskName
    status: Literal[STATUSES]  # type: ignore[valid-type]
    cost_terms: dict[Name, Finite]
    total_cost: Finite | None
    failures: Failures = {}
    duration_s: Duration = 0.0
    wall_s: Duration = 0.0
    telemetry: dict[Name, Finite] = {}
    fault_counts: dict[Name, Count] = {}
    detail: Text = ""
    trace: TraceName = ""
    mcap: McapName = ""

    def _check(self) -> None:
        ok = self.status == "ok"
        get_task(self.task).check_names(self.cost_terms, "cost_terms", complete=ok)
        if ok and self.total_cost is None:
            raise InvalidField("total_cost", "required when status is 'ok'")
        if not ok and self.total_cost is not None:
            raise InvalidField("total_cost", f"must be null when status is {self.status!r}")

    @property
    def ok(self) -> bool:
        """``status == "ok"``."""
        return self.status == "ok"

    def failed(self, flag: str) -> bool:
        """Whether failure flag ``flag`` is set (absent flags are false)."""
        return bool(self.failures.get(flag, False))


class EpisodeDone(Message, frozen=True):
    """Publication on ``episode/done``: one finished episode with its request.

    Attributes:
        robot: the robot's key chunk (as in ``KeySpace.robot``).
        stamp_s: UNIX time (s) at which the episode finished.
        request: the request that was run.
        result: its result; ``episode_id`` and ``task`` must match the request's.
    """

    TYPE: ClassVar[str] = "episode_done"

    robot: Robot
    stamp_s: NonNegative
    request: EpisodeRequest
    result: EpisodeResult

    def _check(self) -> None:
        if self.result.episode_id != self.request.episode_id:
            raise InvalidField("result.episode_id", "does not match request.episode_id")
        if self.result.task != self.request.task:
            raise InvalidField("result.task", "does not match request.task")
