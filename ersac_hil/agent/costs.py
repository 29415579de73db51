"""Cost terms from telemetry (pure functions over a ``Trace``; one function per term).

Every integral is a rectangle sum over the SYNC samples, ``sum(f_k) * dt`` (each sample
stands for one control period). Which terms a task reports, by name, is the task's
(``ersac_hil.agent.tasks``: each task module lists its terms with their units); weights are
configuration (``TASKS[task].default_weights``), never applied here.

Electrical energy is *consumed* energy: per motor and sample, the terminal power I*V counts
only when positive. A motor that is back-driven (the ground pushing the arms, a wheel braking)
generates (I*V < 0); the robot's drives have no regeneration into the battery, so that energy
is burnt in each drive's brake resistor (a chopper across its DC link) and is *not* a credit:
a signed integral would reward being back-driven, e.g. arms that give way under the falling
body. Each drive has its own brake resistor, so there is no exchange between motors either
(clip per motor, then sum).
"""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ersac_hil.agent.robot import UBOT, RobotParameters
from ersac_hil.agent.telemetry import ARM_SLICES, WHEELS_SLICE, Trace
from protocol.can.objects import EmcyCode, Status


def _integral(values: np.ndarray, dt: float) -> float:
    return float(np.sum(values) * dt)


def damage(trace: Trace, emcy_codes: Iterable[int] = ()) -> float:
    broken = bool(trace.status_any() & Status.CABLE_BROKEN) or EmcyCode.CABLE_BROKEN in set(emcy_codes)
    return 1.0 if broken else 0.0


def body_acc_sq(trace: Trace) -> float:
    return _integral(trace.pitch_acc ** 2, trace.dt)


def _power(trace: Trace, columns) -> np.ndarray:
    """Consumed electrical power [W] per sample, shape (n,): sum over ``columns`` of max(I*V, 0)."""
    return np.maximum(trace.current[:, columns] * trace.voltage[:, columns], 0.0).sum(axis=1)


def arm_power(trace: Trace) -> float:
    cols = list(range(ARM_SLICES["left"].start, ARM_SLICES["right"].stop))
    return _integral(_power(trace, cols), trace.dt)


def power(trace: Trace) -> float:
    return _integral(_power(trace, slice(None)), trace.dt)


def wheel_travel(trace: Trace, robot: RobotParameters = UBOT) -> tuple[np.ndarray, np.ndarray]:
    """Ground travel x [m] from the episode's first sample and its rate xdot [m/s], shape (n,)."""
    phi = trace.position[:, WHEELS_SLICE].mean(axis=1)
    phid = trace.velocity[:, WHEELS_SLICE].mean(axis=1)
    x = robot.wheel_radius * (phi + trace.pitch)
    x = x - x[0] if len(x) else x
    return x, robot.wheel_radius * (phid + trace.pitch_rate)


def x_wheel_sq(trace: Trace, robot: RobotParameters = UBOT) -> float:
    return _integral(wheel_travel(trace, robot)[0] ** 2, trace.dt)


def xdot_wheel_sq(trace: Trace, robot: RobotParameters = UBOT) -> float:
    return _integral(wheel_travel(trace, robot)[1] ** 2, trace.dt)


def alpha_sq(trace: Trace) -> float:
    return _integral(trace.pitch ** 2, trace.dt)


def alphadot_sq(trace: Trace) -> float:
    return _integral(trace.pitch_rate ** 2, trace.dt)


def bottle_height(trace: Trace, robot: RobotParameters = UBOT) -> np.ndarray:
    """Bottle height [m] per sample, shape (n,), by forward kinematics."""
    return robot.bottle_height(trace.position[:, ARM_SLICES["left"]],
                               trace.position[:, ARM_SLICES["right"]], trace.pitch)


def h_error_sq(height: np.ndarray, goal_height: float, dt: float) -> float:
    """int (goal - h)^2 dt over the bottle height per sample ``height``, shape (n,)."""
    return _integral((goal_height - height) ** 2, dt)


def summary(trace: Trace, robot: RobotParameters = UBOT) -> dict[str, float]:
    """Telemetry figures every task reports (snake_case names, SI units)."""
    if not len(trace):
        return {"n_cycles": 0.0}
    x, xdot = wheel_travel(trace, robot)
    p_all = _power(trace, slice(None))
    return {
        "n_cycles": float(len(trace)),
        "max_abs_pitch": float(np.abs(trace.pitch).max()),
        "max_abs_pitch_rate": float(np.abs(trace.pitch_rate).max()),
        "max_abs_pitch_acc": float(np.abs(trace.pitch_acc).max()),
        "max_abs_travel_m": float(np.abs(x).max()),
        "max_abs_speed_m_s": float(np.abs(xdot).max()),
        "energy_j": _integral(p_all, trace.dt),
        "peak_current_a": float(np.abs(trace.current).max()),
    }
