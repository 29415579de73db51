"""Policies: what a parameter vector theta means to the robot (pure functions, no I/O).

*Bracing* (theta in [0, 1]): the stiffness of all four arm joints, log-linear between
``k_min`` and ``k_max``::

    K(theta) = k_min * (k_max / k_min) ** theta          [N m/rad], default 20 .. 135

(equal ratios of stiffness per equal step of theta; the range is where the arms' stiffness
shapes the catch: below ~15 N m/rad the arms collapse and the shell strikes the floor, above
~110 the holding energy no longer falls and the elbow cables break for nearly every impact),
with stiffness-proportional damping at the arm boards' own damping time::

    D(theta) = damping_time * K(theta)                   [N m s/rad], damping_time = 10 ms

(the boards' power-on impedance, 50 N m/rad with 0.5 N m s/rad, has the same 10 ms). theta
sets one compliance, spring and damper together: the damping ratio grows with stiffness
(about 0.02 at 5 N m/rad to 0.2 at 450 for the 0.3 kg m^2 arm), so soft arms are springs that
give way under the falling body and stiff arms stop it. A constant damping ratio would make
the soft end viscous rather than soft (a 5 N m/rad arm with 1.7 N m s/rad resists a 4 rad/s
fold with more damping than spring torque); docs/agent.md compares the two.

The arms hold the bracing pose (shoulder, elbow) for ground contact.

*Lifting* (theta = 4 waypoint positions [rad] + 3 segment durations [s]): a cubic Hermite
spline in joint space through start pose -> (shoulder_1, elbow_1) -> (shoulder_2, elbow_2) ->
goal pose, knot times 0, d1, d1 + d2, d1 + d2 + d3; knot velocities by the tangent method
(finite differences over the neighbouring knots, Catmull-Rom for non-uniform times), zero at
both ends::

    v_i = (q_i+1 - q_i-1) / (t_i+1 - t_i-1),   v_0 = v_n-1 = 0

Both arms follow the same spline (a symmetric two-handed lift). Times, positions and
velocities are quantised to what the CAN objects carry (1 ms, 1e-4 rad, 1e-3 rad/s) before
the spline is checked, so the checked spline is exactly the one the boards receive. The check
samples the spline densely and refuses it (``LimitViolation``) if any joint leaves its
position range or exceeds the velocity limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ersac_hil.agent.errors import LimitViolation
from ersac_hil.agent.robot import UBOT, RobotParameters
from protocol.can import objects as obj
from protocol.can.objects import SPLINE_MAX_KNOTS
from protocol.can.spline import hermite_sample
from protocol.zenoh.tasks import LIFTING_GOAL_HEIGHT_M


@dataclass(frozen=True)
class ArmImpedance:
    """Joint impedance of one arm, applied to both: (shoulder, elbow)."""
    stiffness: tuple[float, float]
    damping: tuple[float, float]


@dataclass(frozen=True)
class BracingPolicy:
    """theta -> arm impedance and the bracing pose (see the module docstring).

    Attributes:
        k_min, k_max: stiffness at theta = 0 and theta = 1 [N m/rad].
        damping_time: D / K of every arm joint [s].
        pose: (shoulder, elbow) setpoints held during the episode [rad].
    """
    k_min: float = 20.0
    k_max: float = 135.0
    damping_time: float = 0.01
    pose: tuple[float, float] = (0.5, 0.75)
    robot: RobotParameters = UBOT

    def __post_init__(self) -> None:
        if (not 0 < self.k_min < self.k_max <= self.robot.stiffness_max
                or not 0 < self.damping_time * self.k_max <= self.robot.damping_max):
            raise ValueError(f"invalid bracing map {self}")

    def stiffness(self, theta: float) -> float:
        """K(theta) [N m/rad] for theta in [0, 1] (the contract's bounds, checked where the
        request arrives: ``EpisodeRequest``)."""
        return self.k_min * (self.k_max / self.k_min) ** theta

    def damping(self, theta: float) -> float:
        """D(theta) [N m s/rad]."""
        return self.damping_time * self.stiffness(theta)

    def damping_ratio(self, theta: float) -> tuple[float, float]:
        """(shoulder, elbow) damping ratio D / (2 sqrt(K J)) with the inertia each joint moves
        (``RobotParameters.arm_inertia`` at the bracing pose); for documentation and tests."""
        k, d = self.stiffness(theta), self.damping(theta)
        js, je = self.robot.arm_inertia(self.pose[1])
        return (d / (2 * math.sqrt(k * js)), d / (2 * math.sqrt(k * je)))

    def impedance(self, theta: float) -> ArmImpedance:
        k, d = self.stiffness(theta), self.damping(theta)
        return ArmImpedance((k, k), (d, d))


@dataclass(frozen=True)
class Spline:
    """A cubic Hermite spline for the two axes of one arm (both arms get the same).

    Attributes:
        times: knot times [s] from the start command, shape ``(n,)``, strictly increasing,
            ``times[0] == 0``.
        positions: (shoulder, elbow) at the knots [rad], shape ``(n, 2)``.
        velocities: [rad/s], shape ``(n, 2)``.
    """
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def sample(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at times ``t`` (shape ``(m,)``) -> two ``(m, 2)`` arrays,
        exactly as the arm controller interpolates (``protocol.can.spline``)."""
        return hermite_sample(self.times, self.positions, self.velocities, t)


def tangent_velocities(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Knot velocities by the tangent method: central finite differences over the
    neighbouring knots, zero at the ends. ``times`` (n,), ``positions`` (n, k) -> (n, k)."""
    v = np.zeros_like(positions, dtype=float)
    v[1:-1] = (positions[2:] - positions[:-2]) / (times[2:] - times[:-2])[:, None]
    return v


@dataclass(frozen=True)
class LiftingPolicy:
    """theta (7,) -> arm spline (see the module docstring).

    Attributes:
        goal: (shoulder, elbow) at the end of the lift [rad]: the bottle held at
            ``goal_height`` with the body upright (docs/agent.md).
        start: nominal (shoulder, elbow) at the start, used to check a request before the
            robot is reset; the episode uses the measured start pose.
        goal_height: target bottle height [m].
        velocity_limit: joint velocity limit for the check [rad/s].
        check_dt: sampling step of the limit check [s].
    """
    goal_height: float = LIFTING_GOAL_HEIGHT_M
    goal_elbow: float = 0.3
    start: tuple[float, float] = (0.0, 0.95)
    velocity_limit: float = UBOT.arm_velocity_limit
    check_dt: float = 0.002
    robot: RobotParameters = UBOT

    @property
    def goal(self) -> tuple[float, float]:
        return (self.robot.arm_pose_for_height(self.goal_height, self.goal_elbow), self.goal_elbow)

    def spline(self, theta, start: tuple[float, float] | None = None) -> Spline:
        """The checked, quantised spline for ``theta`` (7 values within the contract's bounds,
        checked where the request arrives: ``EpisodeRequest``) from ``start`` (default: nominal).

        Raises:
            LimitViolation: the trajectory leaves a joint range or exceeds the velocity limit.
        """
        s1, e1, s2, e2, d1, d2, d3 = theta
        q_start = self.start if start is None else start
        times = _quantise(np.cumsum([0.0, d1, d2, d3]), obj.KNOT_TIME)
        positions = _quantise(np.array([q_start, (s1, e1), (s2, e2), self.goal], dtype=float),
                              obj.POSITION)
        velocities = _quantise(tangent_velocities(times, positions), obj.VELOCITY)
        if len(times) > SPLINE_MAX_KNOTS:
            raise LimitViolation(f"{len(times)} knots, the arm boards hold {SPLINE_MAX_KNOTS}")
        spline = Spline(times, positions, velocities)
        self.check(spline)
        return spline

    def check(self, spline: Spline) -> None:
        """Raise ``LimitViolation`` naming the first joint, time and value out of limits."""
        t = np.arange(0.0, spline.duration + self.check_dt, self.check_dt)
        q, qd = spline.sample(t)
        ranges = (self.robot.shoulder_range, self.robot.elbow_range)
        for k, (name, (lo, hi)) in enumerate(zip(("shoulder", "elbow"), ranges)):
            bad = np.flatnonzero((q[:, k] < lo) | (q[:, k] > hi))
            if bad.size:
                i = bad[0]
                raise LimitViolation(f"{name} reaches {q[i, k]:.3f} rad at t = {t[i]:.3f} s, "
                                     f"outside its range [{lo}, {hi}] rad")
            fast = np.flatnonzero(np.abs(qd[:, k]) > self.velocity_limit)
            if fast.size:
                i = fast[0]
                raise LimitViolation(f"{name} reaches {qd[i, k]:.2f} rad/s at t = {t[i]:.3f} s, "
                                     f"above the velocity limit {self.velocity_limit} rad/s")


def _quantise(values: np.ndarray, scale: obj.Scale) -> np.ndarray:
    return np.round(np.asarray(values, dtype=float) / scale.factor) * scale.factor
