"""One object per motor-controller board on the bus, the surface the CANopen nodes call.

Boards: ``wheels`` (wheel_left, wheel_right; torque mode), ``torso`` (torso; impedance),
``arm_left`` (shoulder_left, elbow_left) and ``arm_right`` (shoulder_right, elbow_right).
Configuration setters validate and raise :class:`ConfigRangeError` (SDO abort 0x06090030)
without changing anything; commands that arrive cyclically (torques, setpoints) are clamped
by the firmware instead, as a drive does, and flag current/position limiting in the status.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from protocol.can.objects import OBJECTS, Index

from ..plant.physics import AXES
from .errors import ConfigRangeError, ConfigStateError, UnknownAxisError
from .firmware import Firmware
from .spline import HermiteSpline

STIFFNESS_RANGE = OBJECTS[Index.STIFFNESS].limits
"""N m/rad accepted by the impedance law (the EDS range of 0x2030)."""
DAMPING_RANGE = OBJECTS[Index.DAMPING].limits
"""N m s/rad (the EDS range of 0x2031)."""
VELOCITY_LIMIT_RANGE = (0.01, 30.0)
"""rad/s."""
OVERCURRENT_TIME_RANGE = (0.001, 1.0)
"""s."""

BOARDS: dict[str, tuple[str, ...]] = {
    "wheels": ("wheel_left", "wheel_right"),
    "torso": ("torso",),
    "arm_left": ("shoulder_left", "elbow_left"),
    "arm_right": ("shoulder_right", "elbow_right"),
}


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ConfigRangeError(name, value, -math.inf, math.inf)
    return value


def _in_range(name: str, value: float, low: float, high: float) -> float:
    value = float(value)
    if not low <= value <= high:  # also refuses NaN
        raise ConfigRangeError(name, value, low, high)
    return value


@dataclass(frozen=True)
class AxisStatus:
    """Status bits of one axis (the CAN layer packs them into the status word)."""

    enabled: bool
    safe_state: bool
    over_current: bool
    current_limiting: bool
    position_limit: bool
    spline_active: bool
    spline_done: bool
    disconnected: bool


class MotorController:
    """A board driving ``axes`` through the shared :class:`Firmware` (default: every axis of
    board ``name``; a one-axis drive is the board's controller of one of them).

    The simulator keeps one object per board (and per one-axis drive) for its whole life and
    re-binds it to the firmware of the current episode at every reset (power-on state: no
    stored spline).
    """

    def __init__(self, name: str, firmware: Firmware, axes: tuple[str, ...] | None = None) -> None:
        self.name = name
        self.axes = BOARDS[name] if axes is None else axes
        if not set(self.axes) <= set(BOARDS[name]):
            raise UnknownAxisError(f"board {name!r} has no axes {self.axes}; it has {BOARDS[name]}")
        self._idx = np.array([AXES.index(a) for a in self.axes])
        self.bind(firmware)

    def bind(self, firmware: Firmware) -> None:
        """Attach to ``firmware`` (freshly reset) and forget board-local state."""
        self._fw = firmware
        self.safe_state_reason: str | None = None

    def _axis(self, axis: str) -> int:
        if axis not in self.axes:
            raise UnknownAxisError(f"board {self.name!r} has no axis {axis!r}; it has {self.axes}")
        return AXES.index(axis)

    # ---- states ---------------------------------------------------------------------------
    @property
    def in_safe_state(self) -> bool:
        return bool(self._fw.safe[self._idx].all())

    def enter_safe_state(self, reason: str) -> None:
        """Zero torque on every axis of this board (e.g. the agent's heartbeat was lost)."""
        self.safe_state_reason = reason
        self._fw.set_safe(self._idx, True)

    def clear_faults(self) -> None:
        """Fault reset: leave the safe state (holding the current position) and clear the
        over-current latch. Hardware damage (a broken cable) is not cleared."""
        self.safe_state_reason = None
        self._fw.clear_faults(self._idx)
        if self._fw.safe[self._idx].any():
            self._fw.set_safe(self._idx, False)

    def set_enabled(self, enabled: bool) -> None:
        """Operation enabled (control word ENABLE). Disabled axes produce zero torque."""
        self._fw.set_enabled(self._idx, bool(enabled))

    # ---- configuration --------------------------------------------------------------------
    def set_current_limit(self, axis: str, amps: float) -> None:
        i = self._axis(axis)
        self._fw.current_limit[i] = _in_range(f"{axis}.current_limit", amps, 0.0,
                                              float(self._fw.hw_current_limit[i]))
        self._fw.push()

    def current_limit(self, axis: str) -> float:
        return float(self._fw.current_limit[self._axis(axis)])

    def set_overcurrent_time(self, seconds: float) -> None:
        """Time at the current limit before the over-current fault latches (all axes)."""
        self._fw.overcurrent_time[self._idx] = _in_range(
            f"{self.name}.overcurrent_time", seconds, *OVERCURRENT_TIME_RANGE)
        self._fw.push()

    # ---- status ---------------------------------------------------------------------------
    def board_status(self) -> AxisStatus:
        """Each status bit OR-ed over the board's axes (what the status word reports)."""
        return AxisStatus(*self._fw.flags()[:, self._idx].any(axis=1).tolist())

    def status(self, axis: str) -> AxisStatus:
        i = self._axis(axis)
        fw = self._fw
        return AxisStatus(
            enabled=bool(fw.enabled[i]), safe_state=bool(fw.safe[i]),
            over_current=bool(fw.over_current[i]), current_limiting=bool(fw.current_limiting[i]),
            position_limit=bool(fw.position_limited[i]), spline_active=bool(fw.spline_active[i]),
            spline_done=bool(fw.spline_done[i]), disconnected=bool(fw.disconnected[i]))


class WheelController(MotorController):
    """The two wheel axes in torque (current) mode."""

    def __init__(self, firmware: Firmware, axes: tuple[str, ...] | None = None) -> None:
        super().__init__("wheels", firmware, axes)

    def set_torque(self, left: float, right: float) -> None:
        """Joint-side torque commands (N m), positive drives forward. A cyclic command: the
        driver delivers at most its current limit (status: current limiting); only
        non-finite values are refused."""
        self._fw.set_wheel_torque(_finite("wheel_left.torque", left), _finite("wheel_right.torque", right))

    def set_axis_torque(self, axis: str, torque: float) -> None:
        """The torque command of one wheel (N m), the other's unchanged (a one-axis drive)."""
        i = self._axis(axis)
        left, right = (float(t) for t in self._fw.torque_cmd[:2])
        value = _finite(f"{axis}.torque", torque)
        self._fw.set_wheel_torque(value if i == 0 else left, value if i == 1 else right)

    @property
    def balance_free(self) -> bool:
        return self._fw.wheels_free

    @balance_free.setter
    def balance_free(self, free: bool) -> None:
        """Test-bench switch: the wheel drivers ignore commands (zero current, free wheels)."""
        self._fw.wheels_free = bool(free)
        self._fw.push()


class JointController(MotorController):
    """Torso or arm board: joint impedance around a setpoint or a cubic Hermite spline."""

    def bind(self, firmware: Firmware) -> None:
        super().bind(firmware)
        self._spline: HermiteSpline | None = None
        self._spline_axes: np.ndarray | None = None

    def set_setpoint(self, axis: str, q: float) -> None:
        """Fixed position setpoint (rad), clamped to the position limits."""
        self._fw.set_setpoint(self._axis(axis), _finite(f"{axis}.setpoint", q))

    def setpoint(self, axis: str) -> float:
        return float(self._fw.q_ref[self._axis(axis)])

    def set_joint_torque(self, axis: str, torque: float) -> None:
        """A bare torque command (N m) on an impedance axis, until the next setpoint or
        impedance (``Firmware.set_joint_torque``: its stiffness and damping are replaced)."""
        self._fw.set_joint_torque(self._axis(axis), _finite(f"{axis}.torque", torque))

    def set_impedance(self, axis: str, stiffness: float, damping: float) -> None:
        """K (N m/rad) and D (N m s/rad); both validated before either changes."""
        i = self._axis(axis)
        k = _in_range(f"{axis}.stiffness", stiffness, *STIFFNESS_RANGE)
        c = _in_range(f"{axis}.damping", damping, *DAMPING_RANGE)
        self._fw.stiffness[i], self._fw.damping[i] = k, c
        self._fw.push()

    def impedance(self, axis: str) -> tuple[float, float]:
        i = self._axis(axis)
        return float(self._fw.stiffness[i]), float(self._fw.damping[i])

    def set_position_limits(self, axis: str, low: float, high: float) -> None:
        """Software position limits (rad) inside the mechanical range; low < high."""
        i = self._axis(axis)
        mlo, mhi = float(self._fw.mech_min[i]), float(self._fw.mech_max[i])
        lo = _in_range(f"{axis}.position_limit_min", low, mlo, mhi)
        hi = _in_range(f"{axis}.position_limit_max", high, lo, mhi)
        self._fw.pos_min[i], self._fw.pos_max[i] = lo, hi

    def set_velocity_limit(self, axis: str, limit: float) -> None:
        i = self._axis(axis)
        self._fw.vel_limit[i] = _in_range(f"{axis}.velocity_limit", limit, *VELOCITY_LIMIT_RANGE)

    def load_spline(self, times: Sequence[float], positions, velocities,
                    axes: Sequence[str] | None = None) -> HermiteSpline:
        """Store a spline for ``axes`` (default: all axes of the board, in board order).

        ``positions``/``velocities`` have shape (n_knots, len(axes)) (or (n_knots,) for one
        axis), rad and rad/s. Knot positions must lie within the position limits and knot
        velocities within the velocity limits. Replaces any stored spline; does not start it.
        """
        names = tuple(self.axes if axes is None else axes)
        idx = np.array([self._axis(a) for a in names])
        spline = HermiteSpline.from_knots(times, positions, velocities)
        if spline.n_axes != idx.size:
            raise ConfigRangeError("spline.axes", spline.n_axes, idx.size, idx.size)
        fw = self._fw
        for col, i in enumerate(idx):
            for j, q in enumerate(spline.positions[:, col]):
                if not fw.pos_min[i] <= q <= fw.pos_max[i]:
                    raise ConfigRangeError(f"{AXES[i]}.spline.positions[{j}]", float(q),
                                           float(fw.pos_min[i]), float(fw.pos_max[i]))
            for j, v in enumerate(spline.velocities[:, col]):
                if abs(v) > fw.vel_limit[i]:
                    raise ConfigRangeError(f"{AXES[i]}.spline.velocities[{j}]", float(v),
                                           -float(fw.vel_limit[i]), float(fw.vel_limit[i]))
        self._spline, self._spline_axes = spline, idx
        return spline

    @property
    def spline(self) -> HermiteSpline | None:
        return self._spline

    def start_spline(self) -> None:
        """Start the stored spline at the next physics substep (control word START_SPLINE)."""
        if self._spline is None or self._spline_axes is None:
            raise ConfigStateError(f"board {self.name!r}: no spline loaded")
        if not self._fw.active[self._spline_axes].all():
            raise ConfigStateError(f"board {self.name!r}: axes not operational (safe state, "
                                   "disabled or disconnected)")
        self._fw.start_spline(self._spline_axes, self._spline)
