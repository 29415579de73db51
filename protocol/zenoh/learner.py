"""Learner control-plane payloads: state, critic, kappa, weights, selection, episodes.

Queries on ``learner/critic`` and ``learner/select`` carry their arguments as selector
parameters (``key?theta=0.4``), parsed by :meth:`CriticQuery.from_parameters` and
:meth:`SelectQuery.from_parameters`; their replies and every other payload are JSON messages.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

from .codec import (
    ID_PATTERN,
    as_bool,
    as_choice,
    as_float,
    as_float_map,
    as_float_tuple,
    as_int,
    as_str,
    format_float,
    format_parameters,
    parse_bool,
    parse_float,
    parse_int,
    parse_parameters,
)
from .episode import EpisodeRequest, EpisodeResult
from .errors import InvalidField
from .messages import Message, field_prefix, set_field
from .tasks import get_task

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


def _kappa(value: Any, name: str = "kappa") -> float:
    return as_float(value, name, lo=KAPPA_MIN, hi=KAPPA_MAX)


def _check_objective(j: float, r: float, f: float, kappa: float, path: str) -> None:
    expected = j + kappa * r
    if not math.isclose(f, expected, rel_tol=1e-9, abs_tol=1e-9 * (1.0 + abs(j) + abs(kappa * r))):
        raise InvalidField(path, f"F = {f!r} but J + kappa * r = {expected!r}")


@dataclass(frozen=True)
class LearnerState(Message):
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

    TYPE = "learner_state"

    run_id: str
    task: str
    status: str
    theta: tuple[float, ...]
    sigma: tuple[float, ...]
    kappa: float
    weights: Mapping[str, float]
    episode_count: int

    def __post_init__(self) -> None:
        as_str(self.run_id, "run_id", pattern=ID_PATTERN)
        spec = get_task(self.task)
        as_choice(self.status, "status", LEARNER_STATUSES)
        set_field(self, "theta", spec.check_theta(self.theta))
        sigma = as_float_tuple(self.sigma, "sigma", length=spec.dim, lo=0.0)
        if any(s <= 0.0 for s in sigma):
            raise InvalidField("sigma", "every entry must be > 0")
        set_field(self, "sigma", sigma)
        set_field(self, "kappa", _kappa(self.kappa))
        set_field(self, "weights", spec.check_weights(self.weights))
        set_field(self, "episode_count", as_int(self.episode_count, "episode_count", lo=0))


@dataclass(frozen=True)
class CriticQuery:
    """Selector parameters of ``learner/critic`` (exactly one of ``thetas`` or ``grid``).

    Text form: ``theta=0.1,0.2|0.3,0.4`` (points separated by ``|``, coordinates by ``,``),
    or ``grid=N`` (N points per dimension spanning the task box); optional ``kappa=x`` to
    evaluate F at another kappa than the learner's current one.

    Attributes:
        thetas: points, each of the same length; ``()`` when ``grid`` is used.
        grid: points per dimension in ``[GRID_MIN, GRID_MAX]``, or ``None``.
        kappa: kappa for F, or ``None`` for the learner's current kappa.
    """

    thetas: tuple[tuple[float, ...], ...] = ()
    grid: int | None = None
    kappa: float | None = None

    PARAMETERS = ("theta", "grid", "kappa")

    def __post_init__(self) -> None:
        if not isinstance(self.thetas, (tuple, list)):
            raise InvalidField("theta", f"expected a sequence of points, got {type(self.thetas).__name__}")
        if len(self.thetas) > MAX_CRITIC_POINTS:
            raise InvalidField("theta", f"more than {MAX_CRITIC_POINTS} points")
        points = tuple(as_float_tuple(p, f"theta[{i}]") for i, p in enumerate(self.thetas))
        if len({len(p) for p in points}) > 1:
            raise InvalidField("theta", "points have different dimensions")
        set_field(self, "thetas", points)
        if self.grid is not None:
            set_field(self, "grid", as_int(self.grid, "grid", lo=GRID_MIN, hi=GRID_MAX))
        if (self.grid is None) == (not points):
            raise InvalidField("theta", "give exactly one of 'theta' or 'grid'")
        if self.kappa is not None:
            set_field(self, "kappa", _kappa(self.kappa))

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


@dataclass(frozen=True)
class CriticPoint(Message):
    """One critic prediction: ``J`` = J~(theta), ``r`` = r~(theta) >= 0, ``F`` = J + kappa r."""

    TYPE = "critic_point"

    theta: tuple[float, ...]
    J: float
    r: float
    F: float

    def __post_init__(self) -> None:
        set_field(self, "theta", as_float_tuple(self.theta, "theta"))
        set_field(self, "J", as_float(self.J, "J"))
        set_field(self, "r", as_float(self.r, "r", lo=0.0))
        set_field(self, "F", as_float(self.F, "F"))


@dataclass(frozen=True)
class CriticReply(Message):
    """Reply of ``learner/critic``.

    Attributes:
        task: the learner's task; every point's theta is checked against its bounds.
        kappa: kappa used for F.
        points: 1..MAX_CRITIC_POINTS predictions, with ``F == J + kappa * r``.
    """

    TYPE = "critic_reply"
    NESTED = {"points": (CriticPoint,)}

    task: str
    kappa: float
    points: tuple[CriticPoint, ...]

    def __post_init__(self) -> None:
        spec = get_task(self.task)
        set_field(self, "kappa", _kappa(self.kappa))
        if not isinstance(self.points, (tuple, list)):
            raise InvalidField("points", f"expected a list, got {type(self.points).__name__}")
        if not 1 <= len(self.points) <= MAX_CRITIC_POINTS:
            raise InvalidField("points", f"expected 1..{MAX_CRITIC_POINTS} points")
        for i, point in enumerate(self.points):
            if not isinstance(point, CriticPoint):
                raise InvalidField(f"points[{i}]", "expected a CriticPoint")
            with field_prefix(f"points[{i}]"):
                spec.check_theta(point.theta)
                _check_objective(point.J, point.r, point.F, self.kappa, "F")
        set_field(self, "points", tuple(self.points))


@dataclass(frozen=True)
class KappaCommand(Message):
    """Put on ``learner/kappa``: new risk sensitivity in ``[KAPPA_MIN, KAPPA_MAX]``."""

    TYPE = "kappa_command"

    kappa: float

    def __post_init__(self) -> None:
        set_field(self, "kappa", _kappa(self.kappa))


@dataclass(frozen=True)
class WeightsCommand(Message):
    """Put on ``learner/weights``: new cost-term weights (a risk context).

    ``weights`` is a non-empty name -> finite, non-negative float mapping; names missing keep
    their current weight. Whether the names belong to the learner's task is checked by the
    learner (``TaskSpec.total_cost``), which refuses the whole command if not (``learner/error``).
    """

    TYPE = "weights_command"

    weights: Mapping[str, float]

    def __post_init__(self) -> None:
        set_field(self, "weights", as_float_map(self.weights, "weights", lo=0.0, allow_empty=False))


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


@dataclass(frozen=True)
class SelectQuery:
    """Selector parameters of ``learner/select``: offline policy selection.

    Text form: ``kappa=0.5;weights=damage:10,arm_power:2.5;adopt=true``; ``kappa`` is required,
    ``weights`` (partial, merged over the learner's current weights) and ``adopt`` (make the
    selected theta the learner's policy mean) are optional.
    """

    kappa: float
    weights: Mapping[str, float] | None = None
    adopt: bool = False

    PARAMETERS = ("kappa", "weights", "adopt")

    def __post_init__(self) -> None:
        set_field(self, "kappa", _kappa(self.kappa))
        if self.weights is not None:
            set_field(
                self, "weights", as_float_map(self.weights, "weights", lo=0.0, allow_empty=False)
            )
        as_bool(self.adopt, "adopt")

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


@dataclass(frozen=True)
class SelectReply(Message):
    """Reply of ``learner/select``: the minimiser of F~ = J~ + kappa r~ within the data.

    Attributes:
        task: the learner's task.
        theta: selected parameters within the task bounds.
        J, r, F: critic values at theta, ``r >= 0``, ``F == J + kappa * r``.
        kappa: the kappa used.
        weights: the complete weights used (the task's term names).
        adopted: whether the learner made theta its policy mean.
    """

    TYPE = "select_reply"

    task: str
    theta: tuple[float, ...]
    J: float
    r: float
    F: float
    kappa: float
    weights: Mapping[str, float]
    adopted: bool

    def __post_init__(self) -> None:
        spec = get_task(self.task)
        set_field(self, "theta", spec.check_theta(self.theta))
        set_field(self, "J", as_float(self.J, "J"))
        set_field(self, "r", as_float(self.r, "r", lo=0.0))
        set_field(self, "F", as_float(self.F, "F"))
        set_field(self, "kappa", _kappa(self.kappa))
        _check_objective(self.J, self.r, self.F, self.kappa, "F")
        set_field(self, "weights", spec.check_weights(self.weights))
        as_bool(self.adopted, "adopted")


@dataclass(frozen=True)
class LearnerEpisode(Message):
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

    TYPE = "learner_episode"
    NESTED = {"request": EpisodeRequest, "result": EpisodeResult}

    run_id: str
    index: int
    base_theta: tuple[float, ...]
    z: tuple[float, ...]
    request: EpisodeRequest
    result: EpisodeResult
    cost: float | None
    stamp_s: float

    def __post_init__(self) -> None:
        as_str(self.run_id, "run_id", pattern=ID_PATTERN)
        set_field(self, "index", as_int(self.index, "index", lo=0))
        if not isinstance(self.request, EpisodeRequest):
            raise InvalidField("request", "expected an EpisodeRequest")
        if not isinstance(self.result, EpisodeResult):
            raise InvalidField("result", "expected an EpisodeResult")
        spec = self.request.spec
        set_field(self, "base_theta", spec.check_theta(self.base_theta, "base_theta"))
        set_field(self, "z", as_float_tuple(self.z, "z", length=spec.dim))
        if (self.result.episode_id, self.result.task) != (self.request.episode_id, self.request.task):
            raise InvalidField("result.episode_id", "does not match the request")
        if self.result.ok:
            if self.cost is None:
                raise InvalidField("cost", "required when the result is 'ok'")
            set_field(self, "cost", as_float(self.cost, "cost"))
        elif self.cost is not None:
            raise InvalidField("cost", "must be null when the result is not 'ok'")
        set_field(self, "stamp_s", as_float(self.stamp_s, "stamp_s", lo=0.0))
