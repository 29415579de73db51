"""Balance: discrete-time LQR on the wheel torques of a linearised wheeled inverted pendulum.

Model (sagittal plane, both wheels together; docs/agent.md has the derivation). Generalised
coordinates: ``psi`` the wheels' absolute angle, ``alpha`` the body pitch (forward positive).
The body (everything above the axle, arms held rigid at their pose) has mass ``M``, centre of
mass at distance ``l`` from the axle and pitch inertia ``I_b`` about it; the two wheels have
mass ``m_w``, inertia ``I_w`` and reflected rotor inertia ``J_r`` (on the wheel angle relative
to the body, ``phi = psi - alpha``); ``b`` is the wheel joints' viscous damping; ``u`` is the
torque of *each* wheel motor (both equal), positive driving forward and pitching the body back.
Linearised about the upright balance (centre of mass above the axle)::

    [(m_w+M) r^2 + I_w + J_r    M r l - J_r      ] [psi'']   [ 0        ]   [ 2u - b phi' ]
    [M r l - J_r                M l^2 + I_b + J_r] [alpha''] = [ M g l a  ] + [-2u + b phi' ]

The controller's state is what the sensors give, ``x = [phi, alpha, phi', alpha']`` (wheel
encoders relative to the body, IMU pitch and rate), as deviations from the reference
``alpha_ref`` = the balance pitch for the measured arm pose (``RobotParameters.balance_pitch``)
and ``phi_ref`` = the wheel angle that puts the robot back where the episode started.
Zero-order hold over the SYNC period gives ``x+ = A x + B u``; ``K`` minimises
``sum x'Qx + u'Ru`` (``scipy.linalg.solve_discrete_are``) with ``Q = S' Q_z S`` in the
physical coordinates ``z = [x_ground, alpha, x_ground', alpha'] = S x`` (Bryson's rule, weights
in ``LqrWeights``). ``u = -K (x - x_ref)``, saturated at the wheel torque limit; beyond
``fall_angle`` from the reference the robot has fallen and the wheels are released (zero torque).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from ersac_hil.agent.robot import UBOT, RobotParameters
from ersac_hil.agent.telemetry import Telemetry


@dataclass(frozen=True)
class LqrWeights:
    """Bryson's rule: the largest acceptable excursion of each physical state and of the
    torque; ``Q_z = diag(1/max^2)``, ``R = 1/u_max^2``."""
    x_max: float = 0.5         # m of ground travel
    alpha_max: float = 0.05    # rad of pitch error
    v_max: float = 0.5         # m/s
    alpha_rate_max: float = 0.5  # rad/s
    u_max: float = 1.0         # N m per wheel (the drivers deliver up to 7.85)

    def q_z(self) -> np.ndarray:
        return np.diag(np.array([self.x_max, self.alpha_max, self.v_max, self.alpha_rate_max]) ** -2.0)

    def r(self) -> np.ndarray:
        return np.array([[self.u_max ** -2.0]])


@dataclass(frozen=True)
class PendulumModel:
    """The lumped parameters of the wheeled inverted pendulum (SI units)."""
    body_mass: float
    com_distance: float
    body_inertia: float
    wheel_mass: float
    wheel_inertia: float
    rotor_inertia: float
    wheel_damping: float
    wheel_radius: float
    gravity: float

    @classmethod
    def from_robot(cls, robot: RobotParameters = UBOT, left=(0.0, 0.0), right=(0.0, 0.0),
                   payload: float = 0.0) -> "PendulumModel":
        """Lump the robot with its arms at ``left``/``right`` (shoulder, elbow) and
        ``payload`` kg at the hands. Wheel terms are for both wheels together."""
        cx, cz, inertia = robot.body_com(left, right, payload)
        return cls(body_mass=robot.body_mass(payload), com_distance=math.hypot(cx, cz),
                   body_inertia=inertia, wheel_mass=2 * robot.wheel_mass,
                   wheel_inertia=2 * robot.wheel_inertia, rotor_inertia=2 * robot.wheel_armature,
                   wheel_damping=2 * robot.wheel_damping, wheel_radius=robot.wheel_radius,
                   gravity=robot.gravity)

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """(A_c (4, 4), B_c (4, 1)) for x = [phi, alpha, phi', alpha'], u = torque per wheel."""
        m, l, ib = self.body_mass, self.com_distance, self.body_inertia
        r, jr, b = self.wheel_radius, self.rotor_inertia, self.wheel_damping
        mass = np.array([[(self.wheel_mass + m) * r * r + self.wheel_inertia + jr, m * r * l - jr],
                         [m * r * l - jr, m * l * l + ib + jr]])
        t = np.array([[1.0, 1.0], [0.0, 1.0]])             # (psi, alpha) = T (phi, alpha)
        gravity = np.array([[0.0, 0.0], [0.0, m * self.gravity * l]])
        damping = np.array([[-b, 0.0], [b, 0.0]])          # forces from phi' only
        force_u = np.array([[2.0], [-2.0]])
        inv = np.linalg.inv(mass @ t)
        a = np.zeros((4, 4))
        a[:2, 2:] = np.eye(2)
        a[2:, :2] = inv @ gravity @ t
        a[2:, 2:] = inv @ damping
        bc = np.zeros((4, 1))
        bc[2:] = inv @ force_u
        return a, bc

    def discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Zero-order hold over ``dt``: (A (4, 4), B (4, 1))."""
        a, b = self.continuous()
        aug = np.zeros((5, 5))
        aug[:4, :4], aug[:4, 4:] = a, b
        e = expm(aug * dt)
        return e[:4, :4], e[:4, 4:]


def lqr_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Discrete LQR gain K (1, 4): u = -K x minimises sum x'Qx + u'Ru."""
    p = solve_discrete_are(a, b, q, r)
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)


def physical_transform(radius: float) -> np.ndarray:
    """S (4, 4): z = [x_ground, alpha, x_ground', alpha'] = S [phi, alpha, phi', alpha']."""
    return np.array([[radius, radius, 0, 0], [0, 1, 0, 0], [0, 0, radius, radius], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class BalanceDesign:
    """A computed design: model, discrete matrices, gain and closed-loop poles."""
    model: PendulumModel
    dt: float
    a: np.ndarray
    b: np.ndarray
    k: np.ndarray
    weights: LqrWeights

    @classmethod
    def compute(cls, model: PendulumModel, dt: float, weights: LqrWeights = LqrWeights()
                ) -> "BalanceDesign":
        a, b = model.discrete(dt)
        s = physical_transform(model.wheel_radius)
        k = lqr_gain(a, b, s.T @ weights.q_z() @ s, weights.r())
        return cls(model, dt, a, b, k, weights)

    @property
    def closed_loop_poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.a - self.b @ self.k)


class BalanceController:
    """LQR balance at the SYNC rate (stateful: remembers where the episode started).

    ``start(telemetry)`` at the first cycle, then ``torque(telemetry)`` every cycle. The wheels
    are released (zero torque for the rest of the episode, ``released`` says why) when the
    pitch is more than ``fall_angle`` from the reference (``"fallen"``) or, with
    ``strike_acc`` set, when the IMU's pitch acceleration exceeds it (``"strike"``: bracing,
    where no wheel torque can stop the fall and a saturated LQR fighting the wheel chocks
    only throws the robot about; docs/robot_model.md section 7).
    """

    def __init__(self, design: BalanceDesign, robot: RobotParameters = UBOT,
                 payload: float = 0.0, fall_angle: float = 0.25,
                 strike_acc: float | None = None) -> None:
        self.design, self.robot, self.payload, self.fall_angle = design, robot, payload, fall_angle
        self.strike_acc = strike_acc
        self.k = design.k.reshape(4)
        self.limit = robot.wheel_torque_limit
        self._psi0 = 0.0
        self.released: str | None = None
        self.released_cycle: int | None = None
        self.saturated_cycles = 0

    @property
    def fallen(self) -> bool:
        return self.released == "fallen"

    def reference_pitch(self, tel: Telemetry) -> float:
        return self.robot.balance_pitch(tel.arm_positions("left"), tel.arm_positions("right"),
                                        self.payload)

    def start(self, tel: Telemetry) -> None:
        """Hold the ground position of this sample."""
        self._psi0 = tel.wheel_position_mean + tel.pitch
        self.released = self.released_cycle = None
        self.saturated_cycles = 0

    def _release(self, why: str, tel: Telemetry) -> tuple[float, float]:
        self.released, self.released_cycle = why, tel.cycle
        return (0.0, 0.0)

    def torque(self, tel: Telemetry) -> tuple[float, float]:
        """(left, right) wheel torque [N m] for this cycle."""
        if self.released:
            return (0.0, 0.0)
        alpha_ref = self.reference_pitch(tel)
        err_alpha = tel.pitch - alpha_ref
        if abs(err_alpha) > self.fall_angle:
            return self._release("fallen", tel)
        if self.strike_acc is not None and abs(tel.pitch_acc) > self.strike_acc:
            return self._release("strike", tel)
        phi = tel.wheel_position_mean
        phid = tel.wheel_velocity_mean
        x = np.array([phi - (self._psi0 - alpha_ref), err_alpha, phid, tel.pitch_rate])
        u = -float(self.k @ x)
        if abs(u) > self.limit:
            self.saturated_cycles += 1
            u = math.copysign(self.limit, u)
        return (u, u)
