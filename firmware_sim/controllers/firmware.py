"""The motor-controller firmware of all boards at the physics rate, vectorised over the seven
axes (arrays of shape (7,) in ``AXES`` order).

Per axis:
- wheels (torque mode): commanded joint torque -> current command I = tau / (Kt G), clamped
  at the current limit (the dcmotor driver compensates back-EMF up to its supply voltage);
- torso and arms (joint impedance): tau = K (q_ref - q) + D (qd_ref - qd), realised by the
  dcmotor driver's on-board PD: gains written into the model in motor units
  (kp = K / G^2, kd = D / G^2), setpoints written as controls (G q_ref, G qd_ref). With a
  fixed setpoint qd_ref = 0, i.e. tau = K (q_ref - q) - D qd. Because the law runs inside
  MuJoCo's actuator model, the implicitfast integrator treats its damping implicitly and
  mjd_transitionFD linearisations include it.
- q_ref is a fixed setpoint or a running cubic Hermite spline sampled every substep from a
  table computed at the start command.
- current limiting at the configured limit; the over-current fault latches when the current
  sits at the limit for longer than ``overcurrent_time`` (the axis keeps running, limited).
- safe state (zero torque) per board on command; a disconnected axis (broken cable) has zero
  torque for the rest of the episode.

Per substep the simulator calls :meth:`write_controls` (only does work while a spline runs)
before ``mj_step2`` and :meth:`monitor` after it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..plant.motors import MotorBank
from ..plant.physics import AXES, Physics, as_slice
from .spline import HermiteSpline

WHEELS = np.array([0, 1])
IMPEDANCE = np.arange(2, 7)

DEFAULT_STIFFNESS = np.array([0.0, 0.0, 200.0, 50.0, 50.0, 50.0, 50.0])
"""N m/rad at power-on (torso, arms), as the object dictionaries' defaults."""
DEFAULT_DAMPING = np.array([0.0, 0.0, 2.0, 0.5, 0.5, 0.5, 0.5])
"""N m s/rad at power-on."""
DEFAULT_VELOCITY_LIMIT = 10.0
"""rad/s, reference velocity limit at power-on."""
DEFAULT_OVERCURRENT_TIME = 0.1
"""s of continuous current limiting before the over-current fault latches."""
FLAGS = ("enabled", "safe", "over_current", "current_limiting", "position_limited", "spline_active",
         "spline_done", "disconnected")
"""The per-axis state flags the boards report (the fields of ``AxisStatus``, in its order)."""


@dataclass(eq=False)  # identity: two running splines never compare their arrays
class _RunningSpline:
    axes: np.ndarray          # (k,) axis numbers
    pos_ctrl: np.ndarray      # (k,) ctrl addresses of the pos inputs
    vel_ctrl: np.ndarray      # (k,)
    q_table: np.ndarray       # (N, k) motor-side position setpoints (G q_ref)
    qd_table: np.ndarray      # (N, k) motor-side velocity setpoints (G qd_ref)
    start_tick: int
    ticks: int = field(init=False)                # N
    block: slice | None = field(init=False)       # the ctrl addresses as one slice (pos, vel, pos, ...)
    table: np.ndarray | None = field(init=False)  # (N, 2k) q_table and qd_table interleaved so

    def __post_init__(self) -> None:
        self.ticks = len(self.q_table)
        self.block = ctrl_block(self.pos_ctrl, self.vel_ctrl)
        self.table = None if self.block is None else interleave(self.q_table, self.qd_table)


def ctrl_block(pos_ctrl: np.ndarray, vel_ctrl: np.ndarray) -> slice | None:
    """The slice of ``ctrl`` that holds exactly the inputs ``pos_ctrl[0], vel_ctrl[0],
    pos_ctrl[1], vel_ctrl[1], ...`` in this order (each shape (k,)), or ``None`` when they are
    not contiguous that way."""
    block = as_slice(np.stack([pos_ctrl, vel_ctrl], axis=1).ravel())
    return block if isinstance(block, slice) else None


def interleave(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Columns of ``a`` and ``b`` (each shape (N, k)) alternating: shape (N, 2k),
    ``a[:, 0], b[:, 0], a[:, 1], ...`` (the values copied, not computed)."""
    out = np.empty((a.shape[0], 2 * a.shape[1]), dtype=np.result_type(a, b))
    out[:, 0::2] = a
    out[:, 1::2] = b
    return out


class Firmware:
    """Configuration, references and fault state of every axis; see the module docstring."""

    def __init__(self, physics: Physics, motors: MotorBank) -> None:
        self.physics = physics
        self.motors = motors
        self.dt = physics.timestep
        idx = physics.axes
        self._act = idx.actuator
        self._act_view = idx.actuator_view
        # the seven actuator forces as a view into MuJoCo's data (read every substep)
        self._force = physics.data.actuator_force[self._act_view] if isinstance(self._act_view, slice) else None
        self._abs_force = np.zeros(7)
        self._dof = idx.dof
        self._qpos = idx.qpos
        self._ff = [int(c) for c in idx.ctrl[WHEELS]]
        self._wheel_scale = [0.0, 0.0]
        self._pos_ctrl = idx.ctrl[IMPEDANCE]
        self._vel_ctrl = idx.ctrl[IMPEDANCE] + 1
        self._imp_act = idx.actuator[IMPEDANCE]
        self._gear = motors.gear
        self._kt = motors.kt
        self.hw_current_limit = motors.current_limit.copy()
        lo, hi = zip(*(physics.joint_range(a) for a in AXES))
        self.mech_min = np.array(lo)
        self.mech_max = np.array(hi)
        self.tick = 0
        self._flags = np.zeros((len(FLAGS), 7), dtype=bool)
        self.reset()

    # ---- episode --------------------------------------------------------------------------
    def reset(self) -> None:
        """Power-on defaults; references = current joint positions (call after the scenario
        has placed the robot). Restores the model fields this class edits."""
        q = self.physics.data.qpos[self._qpos]
        self.tick = 0
        self.stiffness = DEFAULT_STIFFNESS.copy()
        self.damping = DEFAULT_DAMPING.copy()
        self.q_ref = np.where(np.isfinite(self.mech_min), q, 0.0)
        self.qd_ref = np.zeros(7)
        self.torque_cmd = np.zeros(7)
        self.current_limit = self.hw_current_limit.copy()
        self.pos_min = self.mech_min.copy()
        self.pos_max = self.mech_max.copy()
        self.vel_limit = np.full(7, DEFAULT_VELOCITY_LIMIT)
        self.overcurrent_time = np.full(7, DEFAULT_OVERCURRENT_TIME)
        # the flags are rows of one array (flags()), every update in place
        self._flags[:] = False
        (self.enabled, self.safe, self.over_current, self.current_limiting, self.position_limited,
         self.spline_active, self.spline_done, self.disconnected) = self._flags
        self.enabled[:] = True
        self.wheels_free = False
        self._sat_count = np.zeros(7, dtype=np.int64)
        self._counting = False
        self._sat_ticks = np.ones(7, dtype=np.int64)
        self._sat_threshold = np.zeros(7)
        self._splines: list[_RunningSpline] = []
        self.push()

    def flags(self) -> np.ndarray:
        """Every flag of ``FLAGS`` of every axis, shape (8, 7) bool (rows ``FLAGS``, columns
        ``AXES``): the status of all boards in one array (the telemetry hot path)."""
        return self._flags.copy()

    @property
    def active(self) -> np.ndarray:
        """Axes that produce torque, shape (7,) bool."""
        return self.enabled & ~self.safe & ~self.disconnected

    # ---- writing the model ----------------------------------------------------------------
    def push(self) -> None:
        """Write gains, limits and references of every axis into the model and controls."""
        m, d = self.physics.model, self.physics.data
        active = self.active
        g2 = self._gear[IMPEDANCE] ** 2
        on = active[IMPEDANCE]
        m.actuator_gainprm[self._imp_act, 4] = np.where(on, self.stiffness[IMPEDANCE] / g2, 0.0)
        m.actuator_gainprm[self._imp_act, 6] = np.where(on, self.damping[IMPEDANCE] / g2, 0.0)
        limit = self._kt * self.current_limit
        m.actuator_forcerange[self._act, 0] = -limit
        m.actuator_forcerange[self._act, 1] = limit
        self._sat_threshold = limit * (1.0 - 1e-9)
        self._sat_threshold_list = self._sat_threshold.tolist()
        self._sat_ticks = np.maximum(1, np.round(self.overcurrent_time / self.dt)).astype(np.int64)
        self._min_sat_ticks = int(self._sat_ticks.min())
        d.ctrl[self._pos_ctrl] = self._gear[IMPEDANCE] * self.q_ref[IMPEDANCE]
        d.ctrl[self._vel_ctrl] = self._gear[IMPEDANCE] * self.qd_ref[IMPEDANCE]
        self._write_wheels()

    def _write_wheels(self) -> None:
        on = self.active[WHEELS] & (not self.wheels_free)
        self._wheel_scale = [1.0 / float(self._gear[i]) if on[i] else 0.0 for i in WHEELS]
        self.set_wheel_torque(float(self.torque_cmd[0]), float(self.torque_cmd[1]))

    # ---- commands (validated by the boards) -----------------------------------------------
    def set_wheel_torque(self, left: float, right: float) -> None:
        """Joint-side torque commands; the motor torque (ff input) is torque / G, or 0 when
        the wheel drivers are inactive or free."""
        self.torque_cmd[0] = left
        self.torque_cmd[1] = right
        ctrl = self.physics.data.ctrl
        ctrl[self._ff[0]] = left * self._wheel_scale[0]
        ctrl[self._ff[1]] = right * self._wheel_scale[1]

    def set_setpoint(self, i: int, q: float) -> None:
        """Fixed setpoint for impedance axis ``i`` (cancels a running spline on that axis)."""
        self.cancel_spline(i)
        clamped = min(max(q, self.pos_min[i]), self.pos_max[i])
        self.position_limited[i] = clamped != q
        self.q_ref[i] = clamped
        self.qd_ref[i] = 0.0
        k = i - 2
        d = self.physics.data
        d.ctrl[self._pos_ctrl[k]] = self._gear[i] * clamped
        d.ctrl[self._vel_ctrl[k]] = 0.0

    TORQUE_SPRING = 1.0
    """N m/rad of the spring ``set_joint_torque`` realises a torque with."""

    def set_joint_torque(self, i: int, torque: float) -> None:
        """A torque command on impedance axis ``i`` through its driver's PD input (the motor
        model has no torque input on these axes): no damping, a ``TORQUE_SPRING`` whose rest
        point lies ``torque / TORQUE_SPRING`` ahead of the present position, unclamped. Placed
        anew at every command (each SYNC), the torque drifts by TORQUE_SPRING times the motion
        within a period (0.05 N m at 10 rad/s and 5 ms). Cancels a running spline."""
        self.cancel_spline(i)
        k = i - 2
        g, m, d = self._gear[i], self.physics.model, self.physics.data
        self.stiffness[i], self.damping[i] = self.TORQUE_SPRING, 0.0
        on = bool(self.active[i])
        act = self._imp_act[k]
        m.actuator_gainprm[act, 4] = self.TORQUE_SPRING / g ** 2 if on else 0.0
        m.actuator_gainprm[act, 6] = 0.0
        rest = float(d.qpos[self._qpos[i]]) + torque / self.TORQUE_SPRING
        self.q_ref[i], self.qd_ref[i] = rest, 0.0
        self.position_limited[i] = False
        d.ctrl[self._pos_ctrl[k]] = g * rest
        d.ctrl[self._vel_ctrl[k]] = 0.0

    def start_spline(self, axes: np.ndarray, spline: HermiteSpline) -> None:
        """Start ``spline`` (one column per axis of ``axes``) at the next substep."""
        for i in axes:
            self.cancel_spline(int(i))
        n = int(math.ceil(spline.duration / self.dt)) + 1
        q, qd = spline.sample(np.arange(n) * self.dt)
        lo, hi = self.pos_min[axes], self.pos_max[axes]
        self.position_limited[axes] = ((q < lo) | (q > hi)).any(axis=0)
        q = np.clip(q, lo, hi)
        qd = np.clip(qd, -self.vel_limit[axes], self.vel_limit[axes])
        g = self._gear[axes]
        self._splines.append(_RunningSpline(
            axes=np.asarray(axes), pos_ctrl=self._pos_ctrl[axes - 2], vel_ctrl=self._vel_ctrl[axes - 2],
            q_table=q * g, qd_table=qd * g, start_tick=self.tick))
        self.spline_active[axes] = True
        self.spline_done[axes] = False

    def cancel_spline(self, i: int) -> None:
        for s in tuple(self._splines):  # _finish removes from the list
            if i in s.axes:
                self._finish(s, completed=False)

    def _finish(self, s: _RunningSpline, completed: bool) -> None:
        """Stop a running spline; the reference stays at its last sample (velocity 0)."""
        self._splines.remove(s)
        j = min(self.tick - s.start_tick, len(s.q_table)) - 1
        last = s.q_table[max(j, 0)] / self._gear[s.axes]
        self.q_ref[s.axes] = last
        self.qd_ref[s.axes] = 0.0
        d = self.physics.data
        d.ctrl[s.pos_ctrl] = last * self._gear[s.axes]
        d.ctrl[s.vel_ctrl] = 0.0
        self.spline_active[s.axes] = False
        self.spline_done[s.axes] = completed

    # ---- states ---------------------------------------------------------------------------
    def set_safe(self, axes: np.ndarray, safe: bool) -> None:
        """Enter (zero torque, splines aborted) or leave the safe state; leaving re-arms the
        impedance axes at their current position (bumpless)."""
        if safe:
            for i in axes:
                self.cancel_spline(int(i))
        self.safe[axes] = safe
        if not safe:
            self._hold_here(axes)
        self.push()

    def set_enabled(self, axes: np.ndarray, enabled: bool) -> None:
        was = self.active.copy()
        self.enabled[axes] = enabled
        if enabled:
            self._hold_here(axes[~was[axes]])
        self.push()

    def disconnect(self, i: int) -> None:
        """The axis lost its transmission (broken cable): zero torque until the next reset."""
        self.cancel_spline(i)
        self.disconnected[i] = True
        self.push()

    def _hold_here(self, axes: np.ndarray) -> None:
        imp = axes[axes >= 2]
        q = self.physics.data.qpos[self._qpos[imp]]
        self.q_ref[imp] = np.clip(q, self.pos_min[imp], self.pos_max[imp])
        self.qd_ref[imp] = 0.0

    def clear_faults(self, axes: np.ndarray) -> None:
        self.over_current[axes] = False
        self._sat_count[axes] = 0

    # ---- the physics-rate loop ------------------------------------------------------------
    def write_controls(self) -> None:
        """Before a substep: sample the running splines."""
        if not self._splines:
            return
        ctrl = self.physics.data.ctrl
        tick = self.tick
        for s in tuple(self._splines):
            j = tick - s.start_tick
            if j < s.ticks:
                if s.block is not None:  # one slice write (the same values)
                    ctrl[s.block] = s.table[j]
                else:
                    ctrl[s.pos_ctrl] = s.q_table[j]
                    ctrl[s.vel_ctrl] = s.qd_table[j]
            else:
                self._finish(s, completed=True)

    def monitor(self) -> tuple[int, ...]:
        """After a substep: current limiting and over-current timing. Returns the axes whose
        over-current fault latched in this substep."""
        self.tick += 1
        force = self._force if self._force is not None else self.physics.data.actuator_force[self._act_view]
        if not self._counting:  # no axis was limiting (the flags are all clear): scalar check first
            for f, threshold in zip(force.tolist(), self._sat_threshold_list):
                if abs(f) >= threshold:
                    break
            else:
                return ()
        force = np.abs(force, out=self._abs_force)
        limiting = np.greater_equal(force, self._sat_threshold, out=self.current_limiting)
        count = self._sat_count
        if not limiting.any():
            if self._counting:
                count[:] = 0
                self._counting = False
            return ()
        self._counting = True
        count += 1
        count *= limiting
        if count.max() < self._min_sat_ticks:
            return ()
        new = (count >= self._sat_ticks) & ~self.over_current
        if not new.any():
            return ()
        self.over_current |= new
        return tuple(int(i) for i in np.flatnonzero(new))
