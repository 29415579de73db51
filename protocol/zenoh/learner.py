"""Learner control-plane payloads: state, critic, kappa, weights, selection, episodes.

Queries on ``learner/critic`` and ``learner/select`` carry their arguments as selector
parameters (``key?theta=0.4``), parsed by :meth:`CriticQuery.from_parameters` and
:meth:`SelectQuery.from_parameters`; their replies and every other payload are JSON messages.
"""

from __future__ import annotations

import itertools
import math
from typing import Annotated, Any, ClassVar, Literal, Self

from msgspec import Meta

from .codec import (
    format_float,
    format_parameters,
    parse_bool,
    parse_float,
    parse_int,
    parse_parameters,
)
from .episode import EpisodeRequest, EpisodeResult
from .errors import InvalidField
from .fields import Count, Finite, Id, Name, NonNegative, Positive, Record
from .messages import Message
from .tasks import TaskName, get_task

__all__ = [
    "KAPPA_MIN",
    "KAPPA_MAX",
    "LEARNER_STATUSES",
    "MAX_CRITIC_POINTS",
    "GRID_MIN",
    "GRID_MAX",
    "LearnerState",
    "CriticQuery",
    "CriticPoint",
    "CriticReply",
    "KappaCommand",
    "WeightsCommand",
    "SelectQuery",
    "SelectReply",
    "LearnerEpisode",
]

#: Accepted range of the risk sensitivity kappa (< 0 risk seeking, > 0 risk averse).
KAPPA_MIN, KAPPA_MAX = -10.0, 10.0
LEARNER_STATUSES: tuple[str, ...] = ("idle", "running", "paused", "stopped", "failed")
#: Most points one critic query or reply may hold.
MAX_CRITIC_POINTS = 3_000
#: Points per dimension of a critic grid query.
GRID_MIN, GRID_MAX = 2, 1001

Kappa = Annotated[float, Meta(ge=KAPPA_MIN, le=KAPPA_MAX)]
#: A point in parameter space (the task's bounds are checked by each record).
Vector = Annotated[tuple[Finite, ...], Meta(min_length=1, max_length=64)]
Weights = Annotated[dict[Name, NonNegative], Meta(min_length=1)]


def _check_objective(j: float, r: float, f: float, kappa: float, path: str) -> None:
    expected = j + kappa * r
    if not math.isclose(f, expected, rel_tol=1e-9, abs_tol=1e-9 * (1.0 + abs(j) + abs(kappa * r))):
        raise InvalidField(path, f"F = {f!r} but J + kappa * r = {expected!r}")


class LearnerState(Message, frozen=True):
    """Reply of ``learner/state``.

    Attributes:
        run_id: id of the learning run.
        task: a key of ``TASKS``.
        status: one of :data:`LEARNER_STATUSES`.
        theta: current policy mean, shape ``(dim,)``, within the task bounds.
        sigma: exploration std per parameter, shape ``(dim,)``, > 0.
        kappa: current risk sensitivity in ``[KAPPA_MIN, KAPPA_MAX]``.
        weights: complete cost weights (exactly the task's term names), >= 0.
        episode_count: episodes recorded in this run.
    """

    TYPE: ClassVar[str] = "learner_state"

    run_id: Id
    task: TaskName
    status: Literal[LEARNER_STATUSES]  # type: ignore[valid-type]
    theta: Vector
    sigma: tuple[Positive, ...]
    kappa: Kappa
    weights: Weights
    episode_count: Count

    def _check(self) -> None:
        spec = get_task(self.task)
        spec.check_theta(self.theta)
        if len(self.sigma) != spec.dim:
            raise InvalidField("sigma", f"expected {spec.dim} values, got {len(self.sigma)}")
        spec.check_names(self.weights, "weights", complete=True)


class CriticQuery(Record, frozen=True):
    """Selector parameters of ``learner/critic`` (exactly one of ``thetas`` or ``grid``).

    Text form: ``theta=0.1,0.2|0.3,0.4`` (points separated by ``|``, coordinates by ``,``),
    or ``grid=N`` (N points per dimension spanning the task box); optional ``kappa=x`` to
    evaluate F at another kappa than the learner's current one.

    Attributes:
        thetas: points, each of the same length; ``()`` when ``grid`` is used.
        grid: points per dimension in ``[GRID_MIN, GRID_MAX]``, or ``None``.
        kappa: kappa for F, or ``None`` for the learner's current kappa.
    """

    thetas: Annotated[tuple[Vector, ...], Meta(max_length=MAX_CRITIC_POINTS)] = ()
    grid: Annotated[int, Meta(ge=GRID_MIN, le=GRID_MAX)] | None = None
    kappa: Kappa | None = None

    PARAMETERS: ClassVar[tuple[str, ...]] = ("theta", "grid", "kappa")

    def _check(self) -> None:
        if len({len(p) for p in self.thetas}) > 1:
            raise InvalidField("theta", "points have different dimensions")
        if (self.grid is None) == (not self.thetas):
            raise InvalidField("theta", "give exactly one of 'theta' or 'grid'")

    @classmethod
    def from_parameters(cls, params: Any) -> Self:
        """Parse selector parameters (text, mapping or ``zenoh.Parameters``)."""
        p = parse_parameters(params, cls.PARAMETERS)
        thetas: list[tuple[float, ...]] = []
        if "theta" in p:
            chunks = p["theta"].split("|")
            if len(chunks) > MAX_CRITIC_POINTS:
                raise InvalidField("theta", f"more than {MAX_CRITIC_POINTS} points")
            for i, chunk in enumerate(chunks):
                thetas.append(
                    tuple(parse_float(x, f"theta[{i}][{j}]") for j, x in enumerate(chunk.split(",")))
                )
        grid = parse_int(p["grid"], "grid") if "grid" in p else None
        kappa = parse_float(p["kappa"], "kappa") if "kappa" in p else None
        return cls(tuple(thetas), grid, kappa)

    def to_parameters(self) -> str:
        """The selector parameter text (inverse of :meth:`from_parameters`)."""
        out: dict[str, str] = {}
        if self.thetas:
            out["theta"] = "|".join(",".join(format_float(x) for x in p) for p in self.thetas)
        if self.grid is not None:
            out["grid"] = str(self.grid)
        if self.kappa is not None:
            out["kappa"] = format_float(self.kappa)
        return format_parameters(out)

    def points_for(self, task: str) -> tuple[tuple[float, ...], ...]:
        """The points to evaluate for ``task``: the given thetas checked against the task
        bounds, or the grid (``grid`` points per dimension, row-major, ``grid**dim`` points).

        Raises:
            InvalidField: wrong dimension, out of bounds, or a grid above MAX_CRITIC_POINTS.
        """
        spec = get_task(task)
        if self.grid is None:
            return tuple(spec.check_theta(p, f"theta[{i}]") for i, p in enumerate(self.thetas))
        if self.grid**spec.dim > MAX_CRITIC_POINTS:
            raise InvalidField(
                "grid", f"{self.grid}**{spec.dim} points exceed the limit {MAX_CRITIC_POINTS}"
            )
        axes = [
            tuple(lo + (hi - lo) * k / (self.grid - 1) for k in range(self.grid))
            for lo, hi in zip(spec.lower, spec.upper)
        ]
        return tuple(itertools.product(*axes))


class CriticPoint(Message, frozen=True):
    """One critic prediction: ``J`` = J~(theta), ``r`` = r~(theta) >= 0, ``F`` = J + kappa r."""

    TYPE: ClassVar[str] = "critic_point"

    theta: Vector
    J: Finite
    r: NonNegative
    F: Finite


class CriticReply(Message, frozen=True):
    """Reply of ``learner/critic``.

    Attributes:
        task: the learner's task; every point's theta is checked against its bounds.
        kappa: kappa used for F.
        points: 1..MAX_CRITIC_POINTS predictions, with ``F == J + kappa * r``.
    """

    TYPE: ClassVar[str] = "critic_reply"

    task: TaskName
    kappa: Kappa
    points: Annotated[tuple[CriticPoint, ...], Meta(min_length=1, max_length=MAX_CRITIC_POINTS)]

    def _check(self) -> None:
        spec = get_task(self.task)
        for i, point in enumerate(self.points):
            spec.check_theta(point.theta, f"points[{i}].theta")
            _check_objective(point.J, point.r, point.F, self.kappa, f"points[{i}].F")


class KappaCommand(Message, frozen=True):
    """Put on ``learner/kappa``: new risk sensitivity in ``[KAPPA_MIN, KAPPA_MAX]``."""

    TYPE: ClassVar[str] = "kappa_command"

    kappa: Kappa


class WeightsCommand(Message, frozen=True):
    """Put on ``learner/weights``: new cost-term weights (a risk context).

    ``weights`` is a non-empty name -> finite, non-negative float mapping; names missing keep
    their current weight. Whether the names belong to the learner's task is checked by the
    learner (``TaskSpec.total_cost``), which refuses the whole command if not (``learner/error``).
    """

    TYPE: ClassVar[str] = "weights_command"

    weights: Weights


def _parse_weights(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in text.split(",") if text else []:
        name, sep, value = item.partition(":")
        if not sep:
            raise InvalidField("weights", f"{item[:80]!r} is not 'name:value'")
        if name in out:
            raise InvalidField(f"weights.{name[:80]}", "given more than once")
        out[name] = parse_float(value, f"weights.{name[:80]}")
    return out


class SelectQuery(Record, frozen=True):
    """Selector parameters of ``learner/select``: offline policy selection.

    Text form: ``kappa=0.5;weights=damage:10,arm_power:2.5;adopt=true``; ``kappa`` is required,
    ``weights`` (partial, merged over the learner's current weights) and ``adopt`` (make the
    selected theta the learner's policy mean) are optional.
    """

    kappa: Kappa
    weights: Weights | None = None
    adopt: bool = False

    PARAMETERS: ClassVar[tuple[str, ...]] = ("kappa", "weights", "adopt")

    @classmethod
    def from_parameters(cls, params: Any) -> Self:
        """Parse selector parameters (text, mapping or ``zenoh.Parameters``)."""
        p = parse_parameters(params, cls.PARAMETERS)
        if "kappa" not in p:
            raise InvalidField("kappa", "required parameter")
        kappa = parse_float(p["kappa"], "kappa")
        weights = _parse_weights(p["weights"]) if "weights" in p else None
        adopt = parse_bool(p["adopt"], "adopt") if "adopt" in p else False
        return cls(kappa, weights, adopt)

    def to_parameters(self) -> str:
        """The selector parameter text (inverse of :meth:`from_parameters`)."""
        out = {"kappa": format_float(self.kappa)}
        if self.weights is not None:
            out["weights"] = ",".join(f"{k}:{format_float(v)}" for k, v in self.weights.items())
        if self.adopt:
            out["adopt"] = "true"
        return format_parameters(out)


class SelectReply(Message, frozen=True):
    """Reply of ``learner/select``: the minimiser of F~ = J~ + kappa r~ within the data.

    Attributes:
        task: the learner's task.
        theta: selected parameters within the task bounds.
        J, r, F: critic values at theta, ``r >= 0``, ``F == J + kappa * r``.
        kappa: the kappa used.
        weights: the complete weights used (the task's term names).
        adopted: whether the learner made theta its policy mean.
    """

    TYPE: ClassVar[str] = "select_reply"

    task: TaskName
    theta: Vector
    J: Finite
    r: NonNegative
    F: Finite
    kappa: Kappa
    weights: Weights
    adopted: bool

    def _check(self) -> None:
        spec = get_task(self.task)
        spec.check_theta(self.theta)
        _check_objective(self.J, self.r, self.F, self.kappa, "F")
        spec.check_names(self.weights, "weights", complete=True)


class LearnerEpisode(Message, frozen=True):
    """Publication on ``learner/episodes``: one episode as the learner recorded it.

    Attributes:
        run_id: the learning run.
        index: 0-based episode index within the run.
        base_theta: policy mean before perturbation, within the task bounds.
        z: the perturbation drawn, shape ``(dim,)`` (``request.theta`` is
            ``base_theta + z`` kept in bounds).
        request, result: what the agent was asked and answered.
        cost: cost under the learner's weights at that time (``None`` if not ``ok``).
        stamp_s: UNIX time (s) of recording.
    """

    TYPE: ClassVar[str] = "learner_episode"

    run_id: Id
    index: Count
    base_theta: Vector
    z: Vector
    request: EpisodeRequest
    result: EpisodeResult
    cost: Finite | None
    stamp_s: NonNegative

    def _check(self) -> None:
        spec = self.request.spec
        spec.check_theta(self.base_theta, "base_theta")
        if len(self.z) != spec.dim:
            raise InvalidField("z", f"expected {spec.dim} values, got {len(self.z)}")
        if (self.result.episode_id, self.result.task) != (self.request.episode_id, self.request.task):
            raise InvalidField("result.episode_id", "does not match the request")
        if self.result.ok and self.cost is None:
            raise InvalidField("cost", "required when the result is 'ok'")
        if not self.result.ok and self.cost is not None:
            raise InvalidField("cost", "must be null when the result is not 'ok'")
