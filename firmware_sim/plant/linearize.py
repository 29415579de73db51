"""Linearised sagittal balance model of the uBot from MuJoCo's finite-difference transition
Jacobians (``mjd_transitionFD``), reduced to the four states a balance controller measures.

Reduced state x = [phi, theta, phi_dot, theta_dot]:
    phi   = wheel angle relative to the body (encoders; both wheels equal), rad
    theta = body pitch (IMU), rad, deviation from the static-balance pitch
Input u = torque on each wheel (N m, both wheels the same).

The full MuJoCo state (tangent positions, velocities) is projected on the subspace spanned by
rigid rolling motions: a unit of phi turns both wheels and moves the base by r; a unit of
theta pitches the base about the axle and also moves it by r (the wheels roll along). Arm,
torso and prop states are held at zero deviation (the impedance laws hold the arms; they are
part of the linearisation through the dcmotor PD). ``A_r = T^+ A T``, ``B_r = T^+ B``.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .physics import WHEEL_RADIUS, Physics


@dataclass(frozen=True)
class BalanceModel:
    """Discrete-time x+ = A x + B u at period ``dt``. A (4, 4), B (4, 1)."""

    A: np.ndarray
    B: np.ndarray
    dt: float

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time (A_c, B_c) via the matrix logarithm of the discrete model."""
        from scipy.linalg import logm
        ac = np.real(logm(self.A)) / self.dt
        # B_d = int_0^dt e^{A_c s} ds B_c  ->  B_c = (A_d - I)^-1 A_c B_d
        bc = np.linalg.solve(self.A - np.eye(4), ac @ self.B)
        return ac, bc

    def lqr_gain(self, q: np.ndarray, r: float) -> np.ndarray:
        """Discrete LQR gain K, shape (1, 4), for u = -K x with state weight ``q`` (4, 4) and
        input weight ``r`` (per N m^2 of wheel torque)."""
        from scipy.linalg import solve_discrete_are
        rr = np.array([[float(r)]])
        p = solve_discrete_are(self.A, self.B, q, rr)
        return np.linalg.solve(rr + self.B.T @ p @ self.B, self.B.T @ p @ self.A)


def _basis(physics: Physics) -> np.ndarray:
    """T, shape (2 nv, 4): full tangent state per unit of the reduced coordinates."""
    m = physics.model
    nv = m.nv
    root = m.body_dofadr[physics.base_id]     # free joint: 3 linear (world), 3 angular (local)
    wheels = physics.axes.dof[:2]
    t = np.zeros((2 * nv, 4))
    for offset, (c_phi, c_theta) in ((0, (0, 1)), (nv, (2, 3))):
        t[offset + wheels, c_phi] = 1.0
        t[offset + root + 0, c_phi] = WHEEL_RADIUS
        t[offset + root + 4, c_theta] = 1.0
        t[offset + root + 0, c_theta] = WHEEL_RADIUS
    return t


def balance_model(physics: Physics, period: float, eps: float = 1e-6) -> BalanceModel:
    """Linearise at the current state (call right after a reset: static balance, zero
    velocity) over ``period`` seconds of zero-order-held wheel torque (an integer number of
    physics steps). ``physics.data`` is left unchanged."""
    m, d = physics.model, physics.data
    steps = int(round(period / m.opt.timestep))
    if steps < 1 or abs(steps * m.opt.timestep - period) > 1e-9:
        raise ValueError("period must be a multiple of the physics timestep")
    nx = 2 * m.nv + m.na
    a = np.zeros((nx, nx))
    b = np.zeros((nx, m.nu))
    mujoco.mjd_transitionFD(m, d, eps, True, a, b, None, None)
    a, b = a[:2 * m.nv, :2 * m.nv], b[:2 * m.nv]
    ad = np.linalg.matrix_power(a, steps)
    bd = sum(np.linalg.matrix_power(a, k) for k in range(steps)) @ b
    t = _basis(physics)
    tp = np.linalg.pinv(t)
    wheel_ctrl = physics.axes.ctrl[:2]
    gear = m.actuator_gear[physics.axes.actuator[:2], 0]
    b_wheel = (bd[:, wheel_ctrl] / gear).sum(axis=1, keepdims=True)   # joint torque on both
    return BalanceModel(A=tp @ ad @ t, B=tp @ b_wheel, dt=period)
