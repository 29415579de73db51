"""Host-side limits on every setpoint the agent sends (pure: no I/O).

Two kinds of setpoint, two rules:

* **cyclic setpoints** (wheel torques, torso and arm position setpoints in every RPDO) are
  clamped into the limits before they go on the bus, as a drive clamps what it receives; every
  clamp is counted per setpoint and the counts go into the episode result's ``fault_counts``
  as ``clamped_<setpoint>`` (cycles clamped), so a run that leaned on a limit says so;
* **a plan** (what theta becomes: the arms' stiffness and damping, a lifting spline's knots
  and its sampled trajectory) outside the limits is refused (``LimitViolation``, reply
  ``invalid_request``) before anything is sent: nothing moves.

The limits come from the robot description (``SetpointLimits.from_description``: each axis's
``torque_limit``, ``position_limits``, ``velocity_limit``, ``stiffness_range`` and
``damping_range``; where two axes share a setpoint, both arms, the tighter of the two), or
from today's uBot constants (``from_robot``, ``agent.robot.UBOT``), which the shipped ``ubot5``
description repeats. Inside the limits nothing changes: a clamp is the identity there, so episodes of the
board profile stay bit for bit the same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ersac_hil.agent.errors import LimitViolation
from ersac_hil.agent.robot import UBOT, RobotParameters
from ersac_hil.agent.telemetry import Commands
from protocol.robot import RobotDescription, default_description


@dataclass(frozen=True)
class SetpointLimits:
    """Attributes (SI units):
        wheel_torque: largest |torque| per wheel [N m].
        torso, shoulder, elbow: position ranges [rad] (low, high).
        stiffness, damping: accepted joint impedance [N m/rad], [N m s/rad] (low, high).
        velocity: largest arm joint velocity of a planned trajectory [rad/s].
    """
    wheel_torque: float
    torso: tuple[float, float]
    shoulder: tuple[float, float]
    elbow: tuple[float, float]
    stiffness: tuple[float, float]
    damping: tuple[float, float]
    velocity: float

    def __post_init__(self) -> None:
        pairs = (self.torso, self.shoulder, self.elbow, self.stiffness, self.damping)
        if not (self.wheel_torque > 0 and self.velocity > 0
                and all(math.isfinite(lo) and math.isfinite(hi) and lo < hi for lo, hi in pairs)):
            raise ValueError(f"invalid setpoint limits {self}")

    @classmethod
    def from_description(cls, description: RobotDescription) -> "SetpointLimits":
        """The description's limits (``ValueError`` naming an axis the agent needs and it lacks)."""
        def axes(*names: str):
            try:
                return [description.axis(n) for n in names]
            except KeyError as exc:
                raise ValueError(f"robot description {description.name}: {exc.args[0]}") from None

        def common(ranges, what: str) -> tuple[float, float]:
            if any(r is None for r in ranges):
                raise ValueError(f"robot description {description.name}: an arm axis has no {what}")
            return max(r.min for r in ranges), min(r.max for r in ranges)

        arms = axes("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
        (torso,) = axes("torso")
        if torso.position_limits is None:
            raise ValueError(f"robot description {description.name}: torso has no position_limits")
        return cls(wheel_torque=min(a.torque_limit for a in axes("wheel_left", "wheel_right")),
                   torso=torso.position_limits.as_tuple(),
                   shoulder=common([arms[0].position_limits, arms[2].position_limits], "position_limits"),
                   elbow=common([arms[1].position_limits, arms[3].position_limits], "position_limits"),
                   stiffness=common([a.stiffness_range for a in arms], "stiffness_range"),
                   damping=common([a.damping_range for a in arms], "damping_range"),
                   velocity=min(a.velocity_limit for a in arms))

    @classmethod
    def default(cls) -> "SetpointLimits":
        """The default description's (``ubot5``)."""
        return cls.from_description(default_description())

    @classmethod
    def from_robot(cls, robot: RobotParameters = UBOT) -> "SetpointLimits":
        """Today's constants of the uBot (``RobotParameters``; the torso's range from the
        default description)."""
        return cls(wheel_torque=robot.wheel_torque_limit, torso=cls.default().torso,
                   shoulder=robot.shoulder_range, elbow=robot.elbow_range,
                   stiffness=(0.0, robot.stiffness_max), damping=(0.0, robot.damping_max),
                   velocity=robot.arm_velocity_limit)

    # -- cyclic setpoints: clamped -----------------------------------------------------------
    def clamp(self, commands: Commands) -> tuple[Commands, tuple[str, ...]]:
        """``commands`` inside the limits, and the names of the setpoints that were clamped
        (``wheel_torque``, ``torso_position``, ``arm_position``); the same object when none was."""
        tl = self.wheel_torque
        left, right = commands.wheel_torque
        torque = (_clip(left, -tl, tl), _clip(right, -tl, tl))
        torso = _clip(commands.torso_position, *self.torso)
        arms = tuple((_clip(s, *self.shoulder), _clip(e, *self.elbow))
                     for s, e in (commands.arm_left, commands.arm_right))
        clamped = tuple(name for name, changed in (
            ("wheel_torque", torque != tuple(commands.wheel_torque)),
            ("torso_position", torso != commands.torso_position),
            ("arm_position", arms != (tuple(commands.arm_left), tuple(commands.arm_right)))) if changed)
        if not clamped:
            return commands, ()
        return replace(commands, wheel_torque=torque, torso_position=torso,
                       arm_left=arms[0], arm_right=arms[1]), clamped

    # -- plans: refused ----------------------------------------------------------------------
    def check_plan(self, setup: Any) -> None:
        """Refuse (``LimitViolation`` naming the value and the limit) a task's setup outside
        the limits: its ``impedance`` (stiffness, damping of each arm joint), its ``pose``,
        its ``spline`` (knot positions, and the trajectory sampled every 10 ms)."""
        impedance = getattr(setup, "impedance", None)
        if impedance is not None:
            for joint, k, d in zip(("shoulder", "elbow"), impedance.stiffness, impedance.damping):
                _within(f"{joint} stiffness", k, self.stiffness, "N m/rad")
                _within(f"{joint} damping", d, self.damping, "N m s/rad")
        pose = getattr(setup, "pose", None)
        if pose is not None:
            _within("shoulder position", pose[0], self.shoulder, "rad")
            _within("elbow position", pose[1], self.elbow, "rad")
        spline = getattr(setup, "spline", None)
        if spline is not None:
            t = np.arange(0.0, spline.duration, 0.01)
            q, qd = spline.sample(np.append(t, spline.duration))
            for k, (joint, box) in enumerate((("shoulder", self.shoulder), ("elbow", self.elbow))):
                positions = np.concatenate([spline.positions[:, k], q[:, k]])
                _within(f"spline {joint} position", float(positions.min()), box, "rad")
                _within(f"spline {joint} position", float(positions.max()), box, "rad")
                fastest = float(np.abs(qd[:, k]).max())
                if fastest > self.velocity:
                    raise LimitViolation(f"plan refused: spline {joint} velocity {fastest:.4g} rad/s is "
                                         f"above the limit {self.velocity:g} rad/s; nothing moved")


def _clip(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


def _within(what: str, value: float, box: tuple[float, float], unit: str) -> None:
    low, high = box
    if not low <= value <= high:  # also refuses NaN
        raise LimitViolation(f"plan refused: {what} {value:.4g} {unit} outside the limits "
                             f"[{low:g}, {high:g}] {unit}; nothing moved")
