"""The robot as the agent knows it: geometry, masses and limits of the uBot-5, and the planar
(sagittal) kinematics the agent needs - bottle height from measured joint angles and body
pitch, and the centre of mass of everything above the wheel axle.

The numbers are those of docs/robot_model.md / firmware_sim/plant/ubot.xml (the agent never
reads the simulator's files; tests/ersac_hil/agent/test_agent_robot.py checks every value here
against the compiled MJCF). The drive constants and limits (wheel motor, joint ranges, velocity
limit, the impedance the arm drives accept) are the robot description's (protocol/robots/ubot5.toml;
``RobotParameters.from_description`` for another one).

Planar convention (the robot's sagittal plane, x forward, z up, origin on the wheel axle):
body pitch ``alpha`` is positive leaning forward; a shoulder angle ``q_s`` is 0 with the arm
hanging and positive raised forward; an elbow angle ``q_e`` is positive flexed forward. In
the world the upper arm points at angle ``q_s - alpha`` from straight down, the forearm at
``q_s + q_e - alpha``::

    shoulder = R(alpha) (0, h_s)
    hand     = shoulder + L_u (sin(q_s - alpha), -cos(q_s - alpha))
                        + L_f (sin(q_s + q_e - alpha), -cos(q_s + q_e - alpha))
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from protocol.robot import RobotDescription, default_description

_AXIS = default_description().axis  # the default robot's drive constants and limits

Trig = TypeVar("Trig", float, np.ndarray)
"""Sines and cosines as floats or as numpy arrays (``RobotParameters._hand``)."""


@dataclass(frozen=True)
class Part:
    """A rigid part for the planar mass model: ``mass`` [kg], centre ``(x, z)`` [m] in its
    parent frame, pitch inertia ``iyy`` [kg m^2] about its own centre."""
    mass: float
    x: float
    z: float
    iyy: float


def _box(mass: float, z: float, hx: float, hz: float) -> Part:
    return Part(mass, 0.0, z, mass * (hx * hx + hz * hz) / 3.0)


def _rod(mass: float, z: float, length: float, radius: float) -> Part:
    # capsule ~ solid cylinder along z: m (3 r^2 + L^2) / 12 about a transverse axis
    return Part(mass, 0.0, z, mass * (3 * radius * radius + length * length) / 12.0)


@dataclass(frozen=True)
class RobotParameters:
    """Geometry, inertia and limits (SI units). Every ``x``/``z`` is in the frame named in
    the field's comment; arm parts hang along -z of their link frame at zero angle.

    Attributes:
        wheel_radius: [m]. wheel_mass / wheel_inertia: per wheel [kg, kg m^2 about the axle].
        wheel_armature: reflected rotor inertia per wheel drive [kg m^2], acting on the wheel
            angle relative to the body. wheel_damping: per wheel joint [N m s/rad].
        wheel_kt, wheel_gear, wheel_current_limit: wheel motor torque constant [N m/A],
            reduction and the driver's current limit [A].
        lower_body: parts fixed to the base (axle frame). torso_height: torso joint above the
            axle [m]; torso_parts in the torso frame. shoulder_height: shoulder above the
            torso frame [m]; half_track, shoulder_y: lateral offsets [m].
        upper_arm_length: shoulder to elbow [m]; hand_offset: elbow to the hand centre [m]
            (where the bottle is held). upper_arm / forearm: parts per arm in the link frames.
        shoulder_range, elbow_range: mechanical joint ranges [rad].
        arm_velocity_limit: default reference velocity limit of the arm boards [rad/s].
        stiffness_max, damping_max: what the arm boards accept [N m/rad, N m s/rad].
        shoulder_armature, elbow_armature: reflected rotor inertias [kg m^2].
        elbow_kt, elbow_gear: elbow motor torque constant [N m/A] and reduction.
        cable_pulley_radius, cable_pretension: the elbow's drive cable runs over a pulley of
            this radius [m], pre-tensioned [N]; its loaded strand carries
            ``pretension + |tau_elbow| / radius`` (``cable_tension``).
        cable_breaking_tension: median breaking tension of an elbow cable [N];
            cable_strength_range: the weakest and the strongest cable [N] (cables differ).
    """
    wheel_radius: float = 0.10
    wheel_mass: float = 1.0
    wheel_inertia: float = 0.5 * 1.0 * 0.10 ** 2
    wheel_armature: float = 0.00906
    wheel_damping: float = 0.002
    wheel_kt: float = _AXIS("wheel_left").torque_constant
    wheel_gear: float = _AXIS("wheel_left").gear
    wheel_current_limit: float = _AXIS("wheel_left").current_limit
    half_track: float = 0.155
    lower_body: tuple[Part, ...] = (_box(8.0, 0.15, 0.07, 0.17), _box(1.4, 0.03, 0.06, 0.04))
    torso_height: float = 0.32
    torso_parts: tuple[Part, ...] = (_box(4.0, 0.11, 0.08, 0.11),)
    shoulder_height: float = 0.20
    shoulder_y: float = 0.155
    upper_arm_length: float = 0.30
    hand_offset: float = 0.32
    upper_arm: tuple[Part, ...] = (_rod(1.0, -0.15, 0.30, 0.03),)
    forearm: tuple[Part, ...] = (_rod(0.6, -0.14, 0.28, 0.025),
                                 Part(0.2, 0.0, -0.32, 0.4 * 0.2 * 0.035 ** 2))
    shoulder_range: tuple[float, float] = _AXIS("shoulder_left").position_limits.as_tuple()
    elbow_range: tuple[float, float] = _AXIS("elbow_left").position_limits.as_tuple()
    arm_velocity_limit: float = _AXIS("shoulder_left").velocity_limit
    stiffness_max: float = _AXIS("shoulder_left").stiffness_range.max
    damping_max: float = _AXIS("shoulder_left").damping_range.max
    shoulder_armature: float = 0.0858
    elbow_armature: float = 0.0482
    gravity: float = 9.81
    elbow_kt: float = 0.0259
    elbow_gear: float = 120.0
    cable_pulley_radius: float = 0.02
    cable_pretension: float = 40.0
    cable_breaking_tension: float = 960.0
    cable_strength_range: tuple[float, float] = (859.0, 1061.0)

    def cable_tension(self, elbow_current: np.ndarray) -> np.ndarray:
        """Tension of the elbow cable's loaded strand [N] from the elbow motor current [A]
        (any shape): the motor torque through the gear, over the pulley."""
        torque = self.elbow_kt * self.elbow_gear * np.abs(np.asarray(elbow_current, dtype=float))
        return self.cable_pretension + torque / self.cable_pulley_radius

    @classmethod
    def from_description(cls, description: RobotDescription, base: "RobotParameters | None" = None
                         ) -> "RobotParameters":
        """``base`` (default: the uBot-5's geometry and masses) with the drive constants and
        limits of ``description``: the left wheel's motor, the left arm's joint ranges, the
        smallest velocity limit and impedance maxima of the four arm axes."""
        d = description
        wheel = d.axis("wheel_left")
        arms = [d.axis(f"{j}_{side}") for j in ("shoulder", "elbow") for side in ("left", "right")]
        shoulder, elbow = d.axis("shoulder_left").position_limits, d.axis("elbow_left").position_limits
        if shoulder is None or elbow is None or any(not a.impedance for a in arms):
            raise ValueError(f"robot description {d.name}: the arm axes need position limits and an impedance")
        return replace(base or cls(), wheel_kt=wheel.torque_constant, wheel_gear=wheel.gear,
                       wheel_current_limit=wheel.current_limit, shoulder_range=shoulder.as_tuple(),
                       elbow_range=elbow.as_tuple(), arm_velocity_limit=min(a.velocity_limit for a in arms),
                       stiffness_max=min(a.stiffness_range.max for a in arms),
                       damping_max=min(a.damping_range.max for a in arms))

    @property
    def wheel_torque_limit(self) -> float:
        """Largest torque per wheel [N m] (at the driver's current limit)."""
        return self.wheel_kt * self.wheel_gear * self.wheel_current_limit

    @property
    def shoulder_z(self) -> float:
        """Shoulder height above the wheel axle in the body frame [m]."""
        return self.torso_height + self.shoulder_height

    @property
    def axle_height(self) -> float:
        """Wheel axle above the floor [m] (wheels on flat ground)."""
        return self.wheel_radius

    # -- kinematics ------------------------------------------------------------------------
    def hand_position(self, shoulder, elbow, pitch) -> tuple[np.ndarray, np.ndarray]:
        """Hand centre (x, z) relative to the axle [m], world frame. Inputs broadcast
        (arrays of shape ``(n,)`` or scalars)."""
        shoulder, elbow, pitch = (np.asarray(a, dtype=float) for a in (shoulder, elbow, pitch))
        a1, a2 = shoulder - pitch, shoulder + elbow - pitch
        return self._hand(np.sin(pitch), np.cos(pitch), np.sin(a1), np.cos(a1), np.sin(a2), np.cos(a2))

    def _hand(self, sin_p: Trig, cos_p: Trig, sin_1: Trig, cos_1: Trig, sin_2: Trig, cos_2: Trig
              ) -> tuple[Trig, Trig]:
        """``hand_position`` from the sines and cosines of the pitch, the upper arm's angle
        ``q_s - alpha`` and the forearm's ``q_s + q_e - alpha`` (the same operations whether
        arrays that broadcast or floats)."""
        x = self.shoulder_z * sin_p + self.upper_arm_length * sin_1 + self.hand_offset * sin_2
        z = self.shoulder_z * cos_p - self.upper_arm_length * cos_1 - self.hand_offset * cos_2
        return x, z

    def bottle_height(self, left, right, pitch) -> np.ndarray:
        """Height above the floor [m] of the bottle held between the hands: the mean of the
        two hand centres. ``left``/``right`` are (shoulder, elbow) arrays of shape ``(n, 2)``
        or ``(2,)``; ``pitch`` shape ``(n,)`` or scalar."""
        left, right = np.asarray(left, dtype=float), np.asarray(right, dtype=float)
        _, zl = self.hand_position(left[..., 0], left[..., 1], pitch)
        _, zr = self.hand_position(right[..., 0], right[..., 1], pitch)
        return self.axle_height + 0.5 * (zl + zr)

    def arm_pose_for_height(self, height: float, elbow: float) -> float:
        """Shoulder angle that puts a hand at ``height`` above the floor with the given elbow
        angle, body upright, the hand in front of the shoulder (the solution below pi) [rad]."""
        # z(q) = h_s - L_u cos q - L_f cos(q + e) = A cos(q + phi) form
        target = height - self.axle_height - self.shoulder_z
        a = -(self.upper_arm_length + self.hand_offset * math.cos(elbow))
        b = self.hand_offset * math.sin(elbow)
        amp, phi = math.hypot(a, b), math.atan2(b, a)   # a cos q + b sin q = amp cos(q - phi)
        if abs(target) > amp:
            raise ValueError(f"height {height} m out of reach with elbow {elbow} rad")
        return phi - math.acos(target / amp)

    # -- mass model ------------------------------------------------------------------------
    def body_mass(self, payload: float = 0.0) -> float:
        """Mass above the axle (everything but the wheels) plus a payload at the hands [kg]."""
        parts = self.lower_body + self.torso_parts + 2 * (self.upper_arm + self.forearm)
        return sum(p.mass for p in parts) + payload

    def mass_points(self, left=(0.0, 0.0), right=(0.0, 0.0), payload: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
        """Every part as a point mass in the body frame (axle origin, body upright), with the
        arms at ``left``/``right`` (shoulder, elbow) and ``payload`` kg at the mean hand
        position: masses, x, z (arrays of shape ``(k,)``) and pitch inertias (a list), in a
        fixed order (body, torso, each arm's upper arm and forearm, the payload)."""
        m: list[float] = []
        xs: list[float] = []
        zs: list[float] = []
        iyy: list[float] = []

        def add(mass: float, x: float, z: float, inertia: float) -> None:
            m.append(mass)
            xs.append(x)
            zs.append(z)
            iyy.append(inertia)

        for p in self.lower_body:
            add(p.mass, p.x, p.z, p.iyy)
        for p in self.torso_parts:
            add(p.mass, p.x, self.torso_height + p.z, p.iyy)
        for shoulder, elbow in (left, right):
            for link_angle, origin, parts in ((shoulder, (0.0, self.shoulder_z), self.upper_arm),
                                              (shoulder + elbow, None, self.forearm)):
                if origin is None:
                    origin = (self.upper_arm_length * math.sin(shoulder),
                              self.shoulder_z - self.upper_arm_length * math.cos(shoulder))
                s, c = math.sin(link_angle), math.cos(link_angle)
                for p in parts:  # part at -z along the link: rotate (p.x, p.z) by the link angle
                    add(p.mass, origin[0] + p.x * c - p.z * s, origin[1] + p.x * s + p.z * c, p.iyy)
        if payload:  # hand_position of both hands, body upright: numpy's sines and cosines in one call each
            (sl, el), (sr, er) = left, right
            angles = np.array([0.0, sl, sl + el, sr, sr + er], dtype=float)  # x - 0.0 is x: pitch 0
            sin, cos = np.sin(angles).tolist(), np.cos(angles).tolist()
            hxl, hzl = self._hand(sin[0], cos[0], sin[1], cos[1], sin[2], cos[2])
            hxr, hzr = self._hand(sin[0], cos[0], sin[3], cos[3], sin[4], cos[4])
            add(payload, 0.5 * (hxl + hxr), 0.5 * (hzl + hzr), 0.0)
        return np.array(m), np.array(xs), np.array(zs), iyy

    @staticmethod
    def _centre(m: np.ndarray, x: np.ndarray, z: np.ndarray) -> tuple[float, float]:
        """Centre ``(x, z)`` of point masses ``m`` at ``x``, ``z`` (shape ``(k,)`` each)."""
        mass = m.sum()
        return float((m * x).sum() / mass), float((m * z).sum() / mass)

    def body_com(self, left=(0.0, 0.0), right=(0.0, 0.0), payload: float = 0.0
                 ) -> tuple[float, float, float]:
        """Centre of mass ``(x, z)`` [m] in the body frame (axle origin, body upright) and the
        pitch inertia about it [kg m^2], with the arms at ``left``/``right`` (shoulder, elbow)
        and ``payload`` kg at the mean hand position."""
        m, x, z, iyy = self.mass_points(left, right, payload)
        cx, cz = self._centre(m, x, z)
        inertia = float((np.array(iyy) + m * ((x - cx) ** 2 + (z - cz) ** 2)).sum())
        return cx, cz, inertia

    def balance_pitch(self, left=(0.0, 0.0), right=(0.0, 0.0), payload: float = 0.0) -> float:
        """Body pitch [rad] that puts the centre of mass straight above the axle (the LQR's
        reference every cycle: the centre alone, no inertia)."""
        cx, cz = self._centre(*self.mass_points(left, right, payload)[:3])
        return -math.atan2(cx, cz)

    def arm_inertia(self, elbow: float = 0.0) -> tuple[float, float]:
        """Inertia [kg m^2] seen by the shoulder (whole arm, elbow at ``elbow``) and by the
        elbow (forearm and hand), rotors included."""
        def about(parts, offset_x, offset_z, angle):
            s, c = math.sin(angle), math.cos(angle)
            return sum(p.iyy + p.mass * ((offset_x + p.x * c - p.z * s) ** 2
                                         + (offset_z + p.x * s + p.z * c) ** 2) for p in parts)
        elbow_j = about(self.forearm, 0.0, 0.0, 0.0) + self.elbow_armature
        shoulder_j = (about(self.upper_arm, 0.0, 0.0, 0.0)
                      + about(self.forearm, 0.0, -self.upper_arm_length, elbow)
                      + self.shoulder_armature)
        return shoulder_j, elbow_j


UBOT = RobotParameters()
"""The uBot-5 the agent drives."""
