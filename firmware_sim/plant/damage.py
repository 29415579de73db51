"""Hardware damage and fall detection: the elbow drive cables and the fall detector.

Elbow cable (one per arm). The elbow is cable driven: the motor and gearbox sit in the upper
arm and a pre-tensioned cable loop over a pulley of radius ``r`` on the elbow carries the
joint torque to the forearm. The loaded strand carries::

    T = T_pre + |tau_elbow| / r,        tau_elbow = G * (motor torque actually applied)

(the equivalent of a spatial tendon that is taut only on its loaded side, without a second
tendon per side). Cables differ in strength (wire-rope tolerance, crimps, wear): each
episode draws each cable's breaking tension around the median (``CableSpec.strength_cv``).
When ``T`` exceeds that cable's strength the cable snaps: the elbow loses its
transmission and goes limp (zero torque, rotor decoupled) for the rest of the episode. The
check runs after every physics substep, so torque spikes inside a control period count.
Stiff bracing arms load the cable most: their impedance torque K * (q_ref - q) grows fastest
when the hands hit the ground.

Fall detector (once per control period): |pitch| above ``pitch_limit`` or any body/shoulder
geom touching the floor.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .physics import AXES, Physics

ELBOWS = ("elbow_left", "elbow_right")
SIDES = ("left", "right")
FALL_GEOMS = ("chassis", "battery", "torso", "upper_arm_left", "upper_arm_right")


@dataclass(frozen=True)
class CableSpec:
    """Elbow cable constants: pulley_radius (m), pretension (N), breaking_tension (N, the
    median strength of a cable), strength_cv (relative standard deviation of the strength from
    cable to cable: each episode's two cables are drawn independently, normal, clipped to
    +-3 cv; 0 = every cable exactly at breaking_tension)."""

    pulley_radius: float = 0.02
    pretension: float = 40.0
    breaking_tension: float = 960.0
    strength_cv: float = 0.035

    def __post_init__(self) -> None:
        if not (self.pulley_radius > 0 and 0 <= self.pretension < self.breaking_tension
                and 0 <= self.strength_cv < 0.3):
            raise ValueError(f"invalid cable spec {self}")

    def draw_strengths(self, rng: np.random.Generator | None) -> np.ndarray:
        """Breaking tension (N) of the left and right cable, shape (2,); the median without
        ``rng``."""
        if rng is None or self.strength_cv == 0.0:
            return np.full(2, self.breaking_tension)
        z = np.clip(rng.standard_normal(2), -3.0, 3.0)
        return self.breaking_tension * (1.0 + self.strength_cv * z)


class ElbowCables:
    """Tension, peak tension and broken state of both elbow cables, index 0 left, 1 right."""

    def __init__(self, physics: Physics, gear: np.ndarray, spec: CableSpec = CableSpec()) -> None:
        self.spec = spec
        idx = [AXES.index(a) for a in ELBOWS]
        self._act = [int(a) for a in physics.axes.actuator[idx]]
        self._dof = physics.axes.dof[idx]
        self._armature0 = physics.model.dof_armature[self._dof].copy()
        self._physics = physics
        # N of tension per N m of motor torque, per side
        self._scale = [float(g) / spec.pulley_radius for g in gear[idx]]
        self.reset()

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """New episode: intact cables; their strengths drawn from ``rng`` (CableSpec).

        ``tension`` and ``peak`` (N, now and the episode's peak) and ``strength`` are two floats
        each, index 0 left, 1 right (plain floats: updated every substep); ``broken`` shape (2,)
        bool."""
        self._physics.model.dof_armature[self._dof] = self._armature0
        self.strength = self.spec.draw_strengths(rng).tolist()
        self.tension = [self.spec.pretension] * 2
        self.peak = list(self.tension)
        self.broken = np.zeros(2, dtype=bool)
        self._intact = [True, True]

    def update(self, actuator_force: np.ndarray) -> tuple[int, ...]:
        """After a substep: tension from the applied motor torques (MuJoCo's actuator_force);
        returns the sides (0 left, 1 right) that broke in this substep."""
        pretension, snapped = self.spec.pretension, ()
        tension, peak, strength = self.tension, self.peak, self.strength
        for side in (0, 1):
            if not self._intact[side]:
                continue
            t = abs(float(actuator_force[self._act[side]])) * self._scale[side] + pretension
            tension[side] = t
            if t > peak[side]:
                peak[side] = t
            if t > strength[side]:
                snapped += (side,)
                self._intact[side] = False
                self.broken[side] = True
                tension[side] = 0.0
                # the rotor and gearbox are no longer coupled to the forearm
                self._physics.model.dof_armature[self._dof[side]] = 0.0
        return snapped


class FallDetector:
    """Latches ``fallen`` when |pitch| > pitch_limit (rad) or a body/shoulder geom touches the floor."""

    def __init__(self, physics: Physics, pitch_limit: float = 0.8) -> None:
        self.pitch_limit = pitch_limit
        self._physics = physics
        self._geoms = frozenset(np.flatnonzero(physics.geom_mask(FALL_GEOMS)).tolist())
        self.fallen = False

    def reset(self) -> None:
        self.fallen = False

    def update(self, pitch: float) -> bool:
        """Check the current state; returns True only when the fall is first detected."""
        if self.fallen:
            return False
        if abs(pitch) > self.pitch_limit or self._physics.contacts_with_floor(self._geoms):
            self.fallen = True
            return True
        return False
