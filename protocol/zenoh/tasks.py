"""Task parameter spaces and cost-term definitions (part of the contract).

Both the learner (which proposes theta and re-weights cost terms) and the agent (which turns
theta into stiffnesses or a spline and integrates the cost terms) use these definitions.

Costs follow Kuindersma, Grupen & Barto (2012):

* ``bracing`` (T = 2 s, theta in [0, 1] = arm stiffness scale for ground contact)::

      J = 10 * damage + 0.1 * int alpha_ddot^2 dt + 5 * int sum_arm I*V dt

  ``damage`` is 1.0 if the hardware was damaged (elbow cable tension above its limit) and
  0.0 otherwise. The paper prints ``h(x(T))`` as a factor; read literally an undamaged trial
  would cost 0, so it is taken as an additive penalty of 10.

* ``lifting`` (T = 6 s, theta = 4 waypoint joint positions [rad] + 3 segment durations [s])::

      J = int x' Q x dt + 0.01 * int sum I*V dt,
      x = [x_wheel, xdot_wheel, alpha_body, alphadot_body, h_error],
      Q = diag(0.001, 0.001, 0.5, 0.5, 0.05)

  Each diagonal entry of Q is the weight of one squared-state integral term.

The agent reports each integral (unweighted) as a named term; the total cost is
``sum(weights[name] * terms[name])`` (:func:`weighted_total`, the one place it is summed: the
agent's reported total, :meth:`TaskSpec.total_cost` and the learner's costs), so past episodes
can be re-weighted exactly when the risk context changes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Literal

from .errors import InvalidField
from .fields import Finite, Name, NonNegative, Positive, Record, convert

__all__ = ["TaskSpec", "TASKS", "TASK_NAMES", "get_task", "weighted_total", "damaged", "LIFTING_GOAL_HEIGHT_M",
           "LIFTING_GOAL_TOLERANCE_M"]


def damaged(terms: Mapping[str, Any]) -> Any:
    """Whether an episode damaged the hardware: its ``damage`` cost term above 0 (a task
    without that term: never). Like :func:`weighted_total`, ``terms`` may hold one episode's
    floats (the result is a bool) or a column per term (numpy arrays: a bool array)."""
    return terms.get("damage", 0.0) > 0


def weighted_total(terms: Mapping[str, Any], weights: Mapping[str, float]) -> Any:
    """``sum(weights[k] * terms[k])`` over the names of ``weights``, in one fixed order.

    The products are accumulated one by one, from ``0.0``, in the sorted order of the names,
    so a total is the same to the last bit wherever it is computed: from one episode's terms
    (floats) or from a column per term holding many episodes' terms (numpy arrays, element by
    element; the result is then an array). No validation: :meth:`TaskSpec.total_cost` and
    the learner's ``CostWeights`` check names and values before they call it.
    """
    total: Any = 0.0
    for name in sorted(weights):
        total = total + weights[name] * terms[name]
    return total


class TaskSpec(Record, frozen=True):
    """The policy parameter space and cost terms of one task.

    Attributes:
        name: task name used on the wire (``"bracing"``, ``"lifting"``).
        param_names: names of the ``dim`` policy parameters, in theta order.
        lower, upper: box bounds of theta, shape ``(dim,)``, ``lower < upper``.
        term_names: names of the cost integrals reported by the agent.
        default_weights: weight per term; ``total = sum(w * term)``.
        horizon_s: episode length T in simulated seconds.
    """

    name: Name
    param_names: tuple[Name, ...]
    lower: tuple[Finite, ...]
    upper: tuple[Finite, ...]
    term_names: tuple[Name, ...]
    default_weights: dict[Name, NonNegative]
    horizon_s: Positive

    def _check(self) -> None:
        n = len(self.param_names)
        if n < 1 or len(set(self.param_names)) != n:
            raise InvalidField("param_names", "must be non-empty and unique")
        for field in ("lower", "upper"):
            if len(getattr(self, field)) != n:
                raise InvalidField(field, f"expected {n} values, got {len(getattr(self, field))}")
        if any(lo >= hi for lo, hi in zip(self.lower, self.upper)):
            raise InvalidField("upper", "every upper bound must exceed its lower bound")
        if len(set(self.term_names)) != len(self.term_names) or not self.term_names:
            raise InvalidField("term_names", "must be non-empty and unique")
        self.check_weights(self.default_weights, "default_weights")

    @property
    def dim(self) -> int:
        """Number of policy parameters."""
        return len(self.param_names)

    def check_theta(self, theta: Any, field: str = "theta") -> tuple[float, ...]:
        """Validate a parameter vector of shape ``(dim,)`` against the bounds.

        Returns:
            theta as a tuple of floats.

        Raises:
            InvalidField: wrong length, not finite, or outside ``[lower, upper]``.
        """
        values = convert(theta, tuple[Finite, ...], field)
        if len(values) != self.dim:
            raise InvalidField(field, f"expected {self.dim} values, got {len(values)}")
        for i, (x, lo, hi) in enumerate(zip(values, self.lower, self.upper)):
            if not lo <= x <= hi:
                raise InvalidField(
                    f"{field}[{i}]",
                    f"{self.param_names[i]} = {x!r} outside [{lo!r}, {hi!r}] of task {self.name!r}",
                )
        return values

    def check_names(self, names: Any, field: str, *, complete: bool) -> None:
        """Every name is one of the task's terms (and, if ``complete``, every term is named)."""
        for name in names:
            if name not in self.term_names:
                raise InvalidField(f"{field}.{name}",
                                   f"not a cost term of {self.name!r}; expected one of {list(self.term_names)}")
        missing = [n for n in self.term_names if n not in names]
        if complete and missing:
            raise InvalidField(field, f"missing entries {missing}")

    def check_weights(self, weights: Any, field: str = "weights") -> Mapping[str, float]:
        """Validate a complete weight set: exactly the task's term names, finite, >= 0."""
        checked = convert(weights, dict[Name, NonNegative], field)
        self.check_names(checked, field, complete=True)
        return checked

    def total_cost(
        self, terms: Mapping[str, float], weights: Mapping[str, float] | None = None
    ) -> float:
        """``sum(weights[k] * terms[k])`` over the task's terms (:func:`weighted_total`).

        Args:
            terms: one value per term name (extra names are an error).
            weights: defaults to :attr:`default_weights`; names missing from a partial
                weight mapping fall back to the defaults.
        """
        checked = convert(terms, dict[Name, Finite], "cost_terms")
        self.check_names(checked, "cost_terms", complete=True)
        w = dict(self.default_weights)
        if weights is not None:
            partial = convert(weights, dict[Name, NonNegative], "weights")
            self.check_names(partial, "weights", complete=False)
            w.update(partial)
        total = weighted_total(checked, w)
        if not math.isfinite(total):
            raise InvalidField("cost_terms", "weighted total is not finite")
        return total


_PI = math.pi

#: Every task the contract knows, by wire name.
TASKS: Mapping[str, TaskSpec] = MappingProxyType(
    {
        "bracing": TaskSpec(
            name="bracing",
            param_names=("arm_stiffness",),
            lower=(0.0,),
            upper=(1.0,),
            term_names=("damage", "body_acc_sq", "arm_power"),
            default_weights={"damage": 10.0, "body_acc_sq": 0.1, "arm_power": 5.0},
            horizon_s=2.0,
        ),
        "lifting": TaskSpec(
            name="lifting",
            # Two intermediate arm waypoints (shoulder, elbow) and three segment durations:
            # start -> waypoint 1 -> waypoint 2 -> goal pose.
            param_names=(
                "shoulder_1", "elbow_1", "shoulder_2", "elbow_2",
                "duration_1", "duration_2", "duration_3",
            ),
            lower=(-1.0, 0.0, -1.0, 0.0, 0.2, 0.2, 0.2),
            upper=(_PI, 2.5, _PI, 2.5, 2.0, 2.0, 2.0),
            term_names=(
                "x_wheel_sq", "xdot_wheel_sq", "alpha_sq", "alphadot_sq", "h_error_sq", "power",
            ),
            default_weights={
                "x_wheel_sq": 0.001,
                "xdot_wheel_sq": 0.001,
                "alpha_sq": 0.5,
                "alphadot_sq": 0.5,
                "h_error_sq": 0.05,
                "power": 0.01,
            },
            horizon_s=6.0,
        ),
    }
)

#: Wire names of the tasks, in a fixed order.
TASK_NAMES: tuple[str, ...] = tuple(TASKS)

#: Lifting's goal: the bottle's centre this high above the floor [m] (the paper's ~120 cm),
#: the height the agent's goal pose and ``h_error_sq`` refer to.
LIFTING_GOAL_HEIGHT_M = 1.2
#: How close to :data:`LIFTING_GOAL_HEIGHT_M` the bottle counts as at the goal [m] (the agent's
#: end condition, the experiments' success criterion).
LIFTING_GOAL_TOLERANCE_M = 0.05


def get_task(name: Any, field: str = "task") -> TaskSpec:
    """The :class:`TaskSpec` called ``name``; :class:`InvalidField` if unknown."""
    if not isinstance(name, str) or name not in TASKS:
        raise InvalidField(field, f"unknown task {name!r}; expected one of {list(TASK_NAMES)}")
    return TASKS[name]

#: The type of a ``task`` field on the wire (a JSON Schema enum of :data:`TASK_NAMES`).
TaskName = Literal[TASK_NAMES]  # type: ignore[valid-type]
