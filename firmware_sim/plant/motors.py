"""DC motor constants of the seven axes, read back from the compiled dcmotor actuators, and
the electrical readouts a motor controller measures.

Per axis (motor side ``m``, joint side ``j``, gear ratio G)::

    tau_j = G * tau_m,   I = tau_m / Kt = tau_j / (Kt G),   V = I R + Ke G omega_j

MuJoCo's dcmotor stores R in ``gainprm[0]``, K = sqrt(Kt Ke) in ``gainprm[1]``, the driver's
supply clamp Vmax in ``gainprm[7]``, the current limit as ``forcerange = K * Imax``; the rotor
inertia is the joint armature divided by G^2. ubot.xml uses Kt = Ke (SI units).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from .physics import AXES, AxisIndex


@dataclass(frozen=True)
class MotorParams:
    """Constants of one axis's motor and gearbox (SI units).

    Attributes:
        axis: axis name. kt: torque constant (N m/A). ke: back-EMF constant (V s/rad).
        resistance: terminal resistance (ohm). gear: reduction G (motor rad per joint rad).
        current_limit: hardware current limit of the driver (A).
        supply_voltage: driver voltage clamp (V). rotor_inertia: motor rotor inertia (kg m^2).
    """

    axis: str
    kt: float
    ke: float
    resistance: float
    gear: float
    current_limit: float
    supply_voltage: float
    rotor_inertia: float

    @property
    def torque_limit(self) -> float:
        """Joint-side torque at the current limit (N m)."""
        return self.kt * self.gear * self.current_limit

    @property
    def no_load_speed(self) -> float:
        """Joint speed at the supply voltage without load (rad/s)."""
        return self.supply_voltage / (self.ke * self.gear)


def read_motor_params(model: mujoco.MjModel) -> dict[str, MotorParams]:
    """MotorParams per axis from the compiled dcmotor actuators of ``model``."""
    index = AxisIndex.from_model(model)
    out: dict[str, MotorParams] = {}
    for i, axis in enumerate(AXES):
        a, dof = index.actuator[i], index.dof[i]
        r, k, vmax = (float(model.actuator_gainprm[a, j]) for j in (0, 1, 7))
        gear = float(model.actuator_gear[a, 0])
        out[axis] = MotorParams(
            axis=axis, kt=k, ke=k, resistance=r, gear=gear,
            current_limit=float(model.actuator_forcerange[a, 1]) / k,
            supply_voltage=vmax,
            rotor_inertia=float(model.dof_armature[dof]) / gear**2,
        )
    return out


class MotorBank:
    """Electrical readouts of the seven motors, ``AXES`` order.

    ``current`` and ``voltage`` take MuJoCo's actuator values (motor-side torque and speed) as
    seven floats and compute axis by axis (what a whole-array formula gives, bit for bit: the
    same IEEE operations in the same order); the constants are arrays of shape (7,).
    """

    def __init__(self, params: dict[str, MotorParams]) -> None:
        self.params = params
        self.kt = np.array([params[a].kt for a in AXES])
        self.ke = np.array([params[a].ke for a in AXES])
        self.resistance = np.array([params[a].resistance for a in AXES])
        self.gear = np.array([params[a].gear for a in AXES])
        self.current_limit = np.array([params[a].current_limit for a in AXES])
        self.supply_voltage = np.array([params[a].supply_voltage for a in AXES])
        self._kt, self._ke, self._r = self.kt.tolist(), self.ke.tolist(), self.resistance.tolist()

    def current(self, motor_torque: Sequence[float]) -> list[float]:
        """Winding current (A) from the motor-side torque (N m), 7 floats."""
        return [torque / kt for torque, kt in zip(motor_torque, self._kt)]

    def voltage(self, current: Sequence[float], motor_speed: Sequence[float]) -> list[float]:
        """Terminal voltage (V) = I R + Ke omega_motor, 7 floats."""
        return [i * r + ke * w for i, r, ke, w in zip(current, self._r, self._ke, motor_speed)]
