"""Named physical overrides of the simulated robot and its firmware (``ersac-hil sim --physics FILE``).

A robot is never exactly its simulator: its cables are weaker or stronger, its motors'
torque constants and current limits differ from the data sheet, its links are heavier. A
physics file states such differences by name, so that a simulator can stand in for "a real
robot that differs from the learner's model" in tests and benchmarks::

    # robot-b.toml: every entry optional; what is not named keeps the model's value
    [cable]                        # both elbow cables
    breaking_tension = 900.0       # N, median strength (model: 960)
    strength_cv = 0.05             # relative scatter of the strength per cable and episode (0.035)
    [motor.shoulder_left]          # any of the seven axes (AXES)
    torque_constant = 0.028        # N m/A, Kt = Ke (model: 0.0259)
    current_limit = 3.0            # A, the driver's hardware limit
    friction = 1.2                 # N m, Coulomb friction of the joint (its gear train)
    [mass]                         # kg per part of the robot (ubot.xml geoms)
    torso = 4.4
    [bracing]
    impact_momentum_mean = 15.0    # N s (model: 14)
    impact_momentum_std = 2.5      # N s (model: 2)
    [bottle]
    shell_mass = 0.4               # kg
    liquid_mass = 0.65             # kg, nominal fill (model: 0.6)
    fill_spread = 0.12             # relative spread of the fill between episodes (0.1)

Names, units and accepted ranges: :data:`PARAMETERS` (``ersac-hil sim --physics-names``
prints them). A file with an unknown name, a value that is not a finite number or a value
outside its range is refused as a whole (:class:`PhysicsError`, one line naming the entry).

Where an override acts: cable constants replace the simulator's ``CableSpec``; motor,
friction and mass entries edit the compiled model's spec after the scenario built it (so they
win over a scenario's own settings, e.g. the lifting bench's 2 A shoulders); a changed torque
constant keeps the axis's current limit (the force range is ``Kt * I_max``); the bracing
impact's clip stays at +-4 standard deviations around the mean; bottle entries act only in
the lifting scenario. No overrides: the model exactly as it is, bit for bit.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import mujoco

from protocol.tomlfile import read_toml

from .damage import CableSpec
from .physics import AXES

__all__ = ["Parameter", "PARAMETERS", "PhysicsError", "PhysicsOverrides", "ROBOT_PARTS"]

#: Parts of the robot whose mass can be overridden (geoms of ubot.xml).
ROBOT_PARTS = ("chassis", "battery", "wheel_left", "wheel_right", "torso", "upper_arm_left",
               "forearm_left", "hand_left", "upper_arm_right", "forearm_right", "hand_right")


class PhysicsError(ValueError):
    """A physics file or entry that is refused (the message names it)."""


@dataclass(frozen=True)
class Parameter:
    """One overridable quantity: dotted ``name``, ``unit``, accepted closed range, meaning."""

    name: str
    unit: str
    lo: float
    hi: float
    doc: str


def _parameters() -> dict[str, Parameter]:
    p = [
        Parameter("cable.breaking_tension", "N", 100.0, 10_000.0, "median breaking tension of an elbow cable"),
        Parameter("cable.strength_cv", "", 0.0, 0.29, "relative scatter of a cable's strength (per cable, episode)"),
        Parameter("cable.pretension", "N", 0.0, 1_000.0, "cable pretension (below the breaking tension)"),
        Parameter("cable.pulley_radius", "m", 0.005, 0.1, "elbow pulley radius"),
        Parameter("bracing.impact_momentum_mean", "N s", 1.0, 40.0, "mean momentum of the bracing strike"),
        Parameter("bracing.impact_momentum_std", "N s", 0.0, 10.0, "standard deviation of the strike's momentum"),
        Parameter("bottle.shell_mass", "kg", 0.05, 5.0, "mass of the lifting bottle's shell"),
        Parameter("bottle.liquid_mass", "kg", 0.0, 5.0, "nominal mass of the bottle's liquid"),
        Parameter("bottle.fill_spread", "", 0.0, 0.4, "relative spread of the liquid's mass between episodes"),
    ]
    for axis in AXES:
        p += [
            Parameter(f"motor.{axis}.torque_constant", "N m/A", 0.001, 1.0, f"{axis} motor torque constant Kt = Ke"),
            Parameter(f"motor.{axis}.current_limit", "A", 0.01, 100.0, f"{axis} driver current limit"),
            Parameter(f"motor.{axis}.friction", "N m", 0.0, 20.0, f"{axis} joint Coulomb friction"),
        ]
    p += [Parameter(f"mass.{part}", "kg", 0.01, 100.0, f"mass of the {part}") for part in ROBOT_PARTS]
    return {q.name: q for q in p}


#: Every overridable quantity by dotted name.
PARAMETERS: dict[str, Parameter] = _parameters()


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def _check(name: str, value: Any) -> float:
    if name not in PARAMETERS:
        raise PhysicsError(f"unknown physical parameter {name!r} (ersac-hil sim --physics-names lists them)")
    q = PARAMETERS[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PhysicsError(f"{name} must be a number ({q.unit or 'dimensionless'}), got {value!r}")
    v = float(value)
    if not math.isfinite(v) or not q.lo <= v <= q.hi:
        unit = f" {q.unit}" if q.unit else ""
        raise PhysicsError(f"{name} = {value!r}{unit} is outside [{q.lo:g}, {q.hi:g}]{unit}")
    return v


@dataclass(frozen=True)
class PhysicsOverrides:
    """Validated overrides, sorted ``(name, value)`` pairs; empty: the model as it is."""

    values: tuple[tuple[str, float], ...] = ()

    @classmethod
    def from_mapping(cls, entries: Mapping[str, Any]) -> PhysicsOverrides:
        """From dotted names (or nested tables, as TOML gives them); :class:`PhysicsError` on
        the first bad entry, in name order."""
        flat = _flatten(entries)
        values = tuple((name, _check(name, flat[name])) for name in sorted(flat))
        out = cls(values)
        try:
            out.cable(CableSpec())
        except ValueError as exc:
            raise PhysicsError(f"cable: pretension must stay below the breaking tension ({exc})") from None
        return out

    @classmethod
    def load(cls, path: str | Path) -> PhysicsOverrides:
        """Read a TOML physics file (:class:`PhysicsError` naming the file on any problem)."""
        data = read_toml(path, PhysicsError)
        try:
            return cls.from_mapping(data)
        except PhysicsError as exc:
            raise PhysicsError(f"{path}: {exc}") from None

    def __bool__(self) -> bool:
        return bool(self.values)

    def as_dict(self) -> dict[str, float]:
        return dict(self.values)

    def get(self, name: str, default: float | None = None) -> float | None:
        return self.as_dict().get(name, default)

    # ------------------------------------------------------------------ where they act
    def cable(self, base: CableSpec) -> CableSpec:
        """``base`` with the cable entries replaced (``ValueError`` if inconsistent)."""
        fields = {k.split(".", 1)[1]: v for k, v in self.values if k.startswith("cable.")}
        return replace(base, **fields) if fields else base

    def apply_spec(self, spec: mujoco.MjSpec) -> None:
        """Edit the scenario's spec before it is compiled: motors, friction, masses, bottle."""
        for name, v in self.values:
            group, _, rest = name.partition(".")
            if group == "motor":
                axis, _, what = rest.partition(".")
                if what == "friction":
                    spec.joint(axis).frictionloss = v
                    continue
                act = spec.actuator(axis)
                k = float(act.gainprm[1])
                i_max = float(act.forcerange[1]) / k
                if what == "torque_constant":
                    act.gainprm[1] = v
                    k = v
                else:
                    i_max = v
                act.forcerange = [-k * i_max, k * i_max]
            elif group == "mass":
                spec.geom(rest).mass = v
            elif name in ("bottle.shell_mass", "bottle.liquid_mass"):
                geom = spec.geom("bottle/" + ("shell" if rest == "shell_mass" else "liquid"))
                if geom is not None:  # only the lifting scenario has a bottle
                    geom.mass = v

    def apply_scenario(self, scenario: object) -> None:
        """Set the scenario's own random quantities (bracing strike, bottle fill)."""
        d = self.as_dict()
        if hasattr(scenario, "momentum_mean") and ("bracing.impact_momentum_mean" in d
                                                    or "bracing.impact_momentum_std" in d):
            mean = d.get("bracing.impact_momentum_mean", scenario.momentum_mean)
            std = d.get("bracing.impact_momentum_std", scenario.momentum_std)
            scenario.momentum_mean, scenario.momentum_std = mean, std
            scenario.momentum_clip = (max(mean - 4.0 * std, 0.0), mean + 4.0 * std)
        if hasattr(scenario, "fill_spread") and "bottle.fill_spread" in d:
            scenario.fill_spread = d["bottle.fill_spread"]

    def describe(self) -> str:
        """One line: ``name=value unit, ...`` (or ``the model's physics``)."""
        if not self.values:
            return "the model's physics"
        return ", ".join(f"{k}={v:g}{' ' + PARAMETERS[k].unit if PARAMETERS[k].unit else ''}"
                         for k, v in self.values)


def names_table() -> str:
    """Every parameter: name, unit, range, meaning (one line each)."""
    return "\n".join(f"{q.name:34s} {q.unit or '-':6s} [{q.lo:g}, {q.hi:g}]  {q.doc}" for q in PARAMETERS.values())
