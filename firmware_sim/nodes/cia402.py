"""A simulated CiA 402 servo drive: one node per axis (``cia402_drive.eds``), over the same plant
and firmware as the boards (``Simulator.axis_controller``: the axis's own share of the board
firmware).

The power state machine (CiA 402 figure 13): NOT READY TO SWITCH ON -> SWITCH ON DISABLED at
boot; shutdown, switch on, enable operation, disable operation, disable voltage, quick stop from
the controlword (0x6040, event-driven RPDO1 or SDO); FAULT on the loss of the agent's heartbeat
(EMCY 0x8130 from the node's consumer watchdog) and on the plant's faults (a broken elbow cable:
EMCY 0xFF10, not resettable: its code stays in 0x603F whatever faults follow); fault reset on
the rising edge of bit 7 -> SWITCH ON DISABLED.
Leaving NMT OPERATIONAL while enabled disables the drive (SWITCH ON DISABLED). The axis produces
torque in OPERATION ENABLED, and in QUICK STOP ACTIVE while it brakes; in every other state none.

Modes (0x6060 -> 0x6061, only those of 0x6502): cyclic synchronous position, the target
(0x607A) followed through the drive's own impedance tau = Kp (target - q) - Kd qdot (0x2012:1/2,
the firmware's joint impedance law at the physics rate); cyclic synchronous torque, the target
torque (0x6071) applied. Both limited to min(0x6072, 0x6073) per mille of the rated current.
Quick stop per 0x605A: 0 torque off at once; otherwise brake (a position axis holds where it
was, a torque axis gets -Kd qdot) and, for 1/2, disable once stopped; 5/6 stay braking.

Telemetry in the profile's units (``protocol.can.cia402.DriveScaling`` of the axis): position
and velocity in encoder increments (per second), torque and current in per mille of rated,
the DC link voltage in mV (the plant's supply).
"""
from __future__ import annotations

from collections.abc import Sequence

from firmware_sim.controllers import (DAMPING_RANGE, STIFFNESS_RANGE, ConfigRangeError, JointController,
                                      WheelController)
from firmware_sim.nodes.base import Key
from firmware_sim.nodes.devices import STATUS_SLOT, CountScale, DeviceApp, Host, counts
from firmware_sim.plant import AXES
from protocol.can import cia402
from protocol.can.cia402 import (CSP, CST, Command, Controlword, DriveScaling, Index, Mode, QuickStopOption,
                                 State, Statusword)
from protocol.can.devices import Device
from protocol.can.objects import EmcyCode

DRIVE_SLOT = STATUS_SLOT + 1
"""Where the drives' counts start in a telemetry row (after the boards' and the IMU's)."""
_DRIVE_INDEXES = (Index.POSITION_ACTUAL, Index.VELOCITY_ACTUAL, Index.TORQUE_ACTUAL, Index.CURRENT_ACTUAL)
_I32, _I16 = ((-(1 << 31), (1 << 31) - 1), (-(1 << 15), (1 << 15) - 1))
STOPPED_RAD_S = 0.01
"""Below this joint speed a braking axis counts as stopped (quick stop options 1 and 2)."""

_ENABLED_BITS = {
    State.SWITCH_ON_DISABLED: Statusword.SWITCH_ON_DISABLED,
    State.READY_TO_SWITCH_ON: Statusword.READY_TO_SWITCH_ON | Statusword.QUICK_STOP | Statusword.VOLTAGE_ENABLED,
    State.SWITCHED_ON: (Statusword.READY_TO_SWITCH_ON | Statusword.SWITCHED_ON | Statusword.QUICK_STOP
                        | Statusword.VOLTAGE_ENABLED),
    State.OPERATION_ENABLED: (Statusword.READY_TO_SWITCH_ON | Statusword.SWITCHED_ON
                              | Statusword.OPERATION_ENABLED | Statusword.QUICK_STOP
                              | Statusword.VOLTAGE_ENABLED),
    State.QUICK_STOP_ACTIVE: (Statusword.READY_TO_SWITCH_ON | Statusword.SWITCHED_ON
                              | Statusword.OPERATION_ENABLED | Statusword.VOLTAGE_ENABLED),
    State.FAULT_REACTION_ACTIVE: (Statusword.READY_TO_SWITCH_ON | Statusword.SWITCHED_ON
                                  | Statusword.OPERATION_ENABLED | Statusword.FAULT),
    State.FAULT: Statusword.FAULT,
}
"""The statusword's state bits of each state (CiA 402 table 30)."""

_TRANSITIONS: dict[tuple[State, Command], State] = {
    (State.SWITCH_ON_DISABLED, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,                # 2
    (State.READY_TO_SWITCH_ON, Command.SWITCH_ON): State.SWITCHED_ON,                      # 3
    (State.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): State.SWITCHED_ON,               # 3 (then 4)
    (State.SWITCHED_ON, Command.ENABLE_OPERATION): State.OPERATION_ENABLED,                # 4
    (State.OPERATION_ENABLED, Command.SWITCH_ON): State.SWITCHED_ON,                       # 5
    (State.SWITCHED_ON, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,                       # 6
    (State.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,         # 7
    (State.READY_TO_SWITCH_ON, Command.QUICK_STOP): State.SWITCH_ON_DISABLED,              # 7
    (State.OPERATION_ENABLED, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,                 # 8
    (State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,          # 9
    (State.SWITCHED_ON, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,                # 10
    (State.SWITCHED_ON, Command.QUICK_STOP): State.SWITCH_ON_DISABLED,                     # 10
    (State.OPERATION_ENABLED, Command.QUICK_STOP): State.QUICK_STOP_ACTIVE,                # 11
    (State.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,          # 12
    (State.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): State.OPERATION_ENABLED,          # 16
}
"""Device control (CiA 402 table 28): (state, command) -> next state (transition number)."""


def drive_scaling(host: Host, joint: str, increments: int) -> DriveScaling:
    """The drive of ``joint`` on the simulated robot: the plant's gear and motor (rated current
    = the driver's current limit), ``increments`` per motor revolution."""
    motor = host.sim.motor(joint)
    return DriveScaling(motor.gear, float(increments), motor.current_limit, motor.kt * motor.current_limit)


class DriveCounts:
    """The drives' telemetry counts of a telemetry row: for every axis of ``AXES``, position
    and velocity in increments (INT32) and torque and current in per mille (INT16), from the
    simulator's ``axis_values`` (torque from the current: tau_motor = Kt I)."""

    def __init__(self, scalings: dict[str, DriveScaling]) -> None:
        self.axes = tuple(a for a in AXES if a in scalings)
        self._col = {a: k for k, a in enumerate(self.axes)}
        rad = [scalings[a].rad_per_increment for a in self.axes]
        amps = [scalings[a].amps_per_mille for a in self.axes]
        self._scales: tuple[CountScale, ...] = (*((f, *_I32) for f in rad), *((f, *_I32) for f in rad),
                                                *((f, *_I16) for f in amps), *((f, *_I16) for f in amps))
        idx = [AXES.index(a) for a in self.axes]
        n = len(AXES)
        self._pick = [*idx, *(n + i for i in idx), *(2 * n + i for i in idx), *(2 * n + i for i in idx)]

    def slot(self, index: int, joint: str) -> int:
        return DRIVE_SLOT + _DRIVE_INDEXES.index(index) * len(self.axes) + self._col[joint]

    def row(self, values: Sequence[float]) -> list[int]:
        """``values``: ``Simulator.axis_values`` (28 floats)."""
        return counts([values[i] for i in self._pick], self._scales)


class DriveApp(DeviceApp):
    """The CiA 402 drive of one axis (``device.joints[0]``); see the module docstring."""

    def __init__(self, host: Host, device: Device, scaling: DriveScaling, drive_counts: DriveCounts) -> None:
        super().__init__(host, device)
        self.joint = device.joints[0]
        self.scaling = scaling
        self.slots = {(Index.STATUSWORD, 0): STATUS_SLOT,
                      **{(index, 0): drive_counts.slot(index, self.joint) for index in _DRIVE_INDEXES}}
        self.torque_axis = self.joint.startswith("wheel")
        self.state = State.SWITCH_ON_DISABLED
        self.mode = Mode.NO_MODE
        self.controlword = 0
        self.error = EmcyCode.NO_ERROR
        self.broken = False

    def attach(self, node) -> None:  # noqa: ANN001 - SlaveNode
        super().attach(node)
        self._identity()
        self._publish()

    def _identity(self) -> None:
        """The motor's and encoder's constants (read-only objects) into the node's values."""
        s, node = self.scaling, self.node
        gear = s.gear if float(s.gear).is_integer() else round(s.gear * 1000)
        for (index, sub), value in {
                (Index.RATED_CURRENT, 0): round(s.rated_current * 1000),
                (Index.RATED_TORQUE, 0): round(s.rated_torque * 1000),
                (Index.ENCODER_RESOLUTION, 1): int(s.increments), (Index.ENCODER_RESOLUTION, 2): 1,
                (Index.GEAR_RATIO, 1): int(gear), (Index.GEAR_RATIO, 2): 1 if float(s.gear).is_integer() else 1000,
                (Index.SUPPORTED_MODES, 0): cia402.SUPPORTED_MODES}.items():
            node.set_value(index, sub, value)

    # -- the axis --------------------------------------------------------------------------
    @property
    def axis(self) -> WheelController | JointController:
        return self.host.sim.axis_controller(self.joint)  # type: ignore[return-value]

    def _position(self) -> float:
        return self.host.sim.axis(self.joint).position

    def _gains(self) -> tuple[float, float]:
        v = self.node.value
        return (int(v(Index.IMPEDANCE, 1)) * cia402.KP_FACTOR, int(v(Index.IMPEDANCE, 2)) * cia402.KD_FACTOR)

    def _torque_on(self) -> bool:
        return self.state in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)

    def _arm(self) -> None:
        """Apply state and mode to the axis: torque on or off, the mode's law with its last
        target (a position axis holds where it is without one)."""
        axis = self.axis
        on = self._torque_on()
        axis.set_enabled(on)
        if not on:
            return
        if self.state is State.QUICK_STOP_ACTIVE:
            self._brake()
        elif self.mode is CSP:
            self._csp(self.node.received(Index.TARGET_POSITION))
        elif self.mode is CST:
            self._cst(self.node.received(Index.TARGET_TORQUE) or 0)
        else:  # enabled without a mode: no command, no torque
            self._cst(0)

    def _csp(self, target: int | None) -> None:
        if self.torque_axis:  # a wheel turns without end: no position law on this axis
            self._cst(0)
            return
        axis: JointController = self.axis  # type: ignore[assignment]
        k, d = self._gains()
        axis.set_impedance(self.joint, k, d)
        q = self._position() if target is None else self.scaling.position(target)
        axis.set_setpoint(self.joint, q)

    def _cst(self, per_mille: int) -> None:
        torque = self.scaling.torque(per_mille)
        if self.torque_axis:
            self.axis.set_axis_torque(self.joint, torque)  # type: ignore[union-attr]
        else:
            self.axis.set_joint_torque(self.joint, torque)  # type: ignore[union-attr]

    def _brake(self) -> None:
        """Quick stop: a position axis holds where it is (its impedance damps it to rest), a
        torque axis gets -Kd qdot (re-computed every SYNC, ``on_sync``)."""
        if self.quick_stop_option is QuickStopOption.DISABLE_DRIVE:
            return
        if self.torque_axis or self.mode is CST:
            if self.torque_axis:
                _, kd = self._gains()
                self.axis.set_axis_torque(self.joint, -kd * self.host.sim.axis(self.joint).velocity)  # type: ignore[union-attr]
            else:
                self._csp(None)
        else:
            self._csp(None)

    @property
    def quick_stop_option(self) -> QuickStopOption:
        return QuickStopOption(int(self.node.value(Index.QUICK_STOP_OPTION)))

    # -- state machine ---------------------------------------------------------------------
    def _enter(self, state: State) -> None:
        if state is State.QUICK_STOP_ACTIVE and self.quick_stop_option is QuickStopOption.DISABLE_DRIVE:
            state = State.SWITCH_ON_DISABLED
        self.state = state
        self._arm()
        self._publish()

    def _publish(self) -> None:
        """Statusword and mode display into the node's values; the event-driven TPDO1 goes out
        if they changed."""
        node = self.node
        node.set_value(Index.STATUSWORD, 0, self.statusword())
        node.set_value(Index.MODES_DISPLAY, 0, int(self.mode))
        node.set_value(Index.ERROR_CODE, 0, int(self.error))
        node.send_event_tpdos()

    def statusword(self) -> int:
        word = _ENABLED_BITS[self.state] | Statusword.REMOTE
        if self.state is State.OPERATION_ENABLED and self.mode in (CSP, CST):
            word |= Statusword.DRIVE_FOLLOWS
        return int(word)

    def _control(self, word: int) -> None:
        rising = word & ~self.controlword
        self.controlword = word
        if rising & Controlword.FAULT_RESET and self.state is State.FAULT:
            if not self.broken:
                self.error = EmcyCode.NO_ERROR
                self.axis.clear_faults()
                self._enter(State.SWITCH_ON_DISABLED)
            return
        command = Command.of(word)
        nxt = _TRANSITIONS.get((self.state, command)) if command is not None else None
        if nxt is not None:
            self._enter(nxt)

    def _set_mode(self, value: int) -> bool:
        try:
            mode = Mode(value)
        except ValueError:
            return False
        if mode is not Mode.NO_MODE and not cia402.SUPPORTED_MODES & mode.supported_bit:
            return False
        if mode is not self.mode:
            self.mode = mode
            if self.state is State.OPERATION_ENABLED:
                self._arm()
            self._publish()
        return True

    def fault(self, code: EmcyCode) -> None:
        """Fault reaction: torque off, FAULT (the caller sends the EMCY)."""
        self.broken = self.broken or code == EmcyCode.CABLE_BROKEN
        self.error = EmcyCode.CABLE_BROKEN if self.broken else code  # why a reset will not clear it
        self.state = State.FAULT
        self.axis.set_enabled(False)
        self._publish()

    # -- NodeApplication hooks ---------------------------------------------------------------
    def on_commands(self, changed: dict[Key, int]) -> None:
        with self.host.lock:
            if (Index.MODES_OF_OPERATION, 0) in changed:
                self._set_mode(changed[(Index.MODES_OF_OPERATION, 0)])
            if (Index.CONTROLWORD, 0) in changed:
                self._control(changed[(Index.CONTROLWORD, 0)])
            if self.state is not State.OPERATION_ENABLED:
                return
            if self.mode is CSP and (Index.TARGET_POSITION, 0) in changed:
                self._csp(changed[(Index.TARGET_POSITION, 0)])
            elif self.mode is CST and (Index.TARGET_TORQUE, 0) in changed:
                self._cst(changed[(Index.TARGET_TORQUE, 0)])

    def on_sync(self) -> None:
        """Before the physics step: a braking torque axis is re-braked; a drive whose quick stop
        ends in SWITCH ON DISABLED (0x605A 1/2) disables once stopped."""
        if self.state is not State.QUICK_STOP_ACTIVE:
            return
        option = self.quick_stop_option
        if option in (QuickStopOption.SLOW_DOWN_RAMP, QuickStopOption.QUICK_STOP_RAMP) and \
                abs(self.host.sim.axis(self.joint).velocity) < STOPPED_RAD_S:
            self._enter(State.SWITCH_ON_DISABLED)
        elif self.torque_axis:
            self._brake()

    def on_failure(self, code: EmcyCode) -> None:
        """A plant fault of this axis (the simulator's failure events)."""
        if code == EmcyCode.CABLE_BROKEN:
            with self.host.lock:
                self.fault(code)

    def on_nmt_state(self, state: str) -> None:
        with self.host.lock:
            self.operational = state == "OPERATIONAL"
            if not self.operational and self._torque_on():
                self._enter(State.SWITCH_ON_DISABLED)  # communication lost: disable
            else:
                self.axis.set_enabled(self._torque_on())

    def on_heartbeat_lost(self) -> None:
        with self.host.lock:
            self.fault(EmcyCode.HEARTBEAT_LOST)

    def on_reset(self) -> None:
        """Power-on: SWITCH ON DISABLED, no mode, no fault but a broken cable's (a new
        scenario: the plant is whole again)."""
        self.state, self.mode, self.controlword = State.SWITCH_ON_DISABLED, Mode.NO_MODE, 0
        self.error, self.broken = EmcyCode.NO_ERROR, False
        with self.host.lock:
            self.axis.set_enabled(False)
        self._identity()
        self._publish()

    def status_word(self, axes) -> int:  # noqa: ANN001 - the sampler's signature
        return self.statusword()

    def sample(self) -> None:
        row = self.host.telemetry()
        row[STATUS_SLOT] = self.statusword()
        self.node.values.update((key, row[slot]) for key, slot in self.slots.items())

    def read(self, key: Key) -> int | None:
        index, sub = key
        if index == Index.STATUSWORD:
            return self.statusword()
        if index in _DRIVE_INDEXES:
            with self.host.lock:
                self.sample()
            return None
        if index == Index.DC_LINK_VOLTAGE:
            with self.host.lock:
                return round(1000 * self.host.sim.motor(self.joint).supply_voltage)
        if index == Index.MODES_DISPLAY:
            return int(self.mode)
        return None

    def configure(self, key: Key, value) -> None:
        index, sub = key
        if index == Index.CONTROLWORD:
            self._control(int(value))
        elif index == Index.MODES_OF_OPERATION:
            if not self._set_mode(int(value)):
                raise ConfigRangeError("modes of operation", value, 0, 0)
        elif index == Index.QUICK_STOP_OPTION:
            try:
                QuickStopOption(int(value))
            except ValueError as exc:
                raise ConfigRangeError("quick stop option code", value, 0, 6) from exc
        elif index == Index.IMPEDANCE:
            if not self.torque_axis:
                k, d = self._gains()
                k, d = (value * cia402.KP_FACTOR, d) if sub == 1 else (k, value * cia402.KD_FACTOR)
                if self.state is State.OPERATION_ENABLED and self.mode is CSP:
                    self.axis.set_impedance(self.joint, k, d)  # type: ignore[union-attr]
                elif not (STIFFNESS_RANGE[0] <= k <= STIFFNESS_RANGE[1]
                        and DAMPING_RANGE[0] <= d <= DAMPING_RANGE[1]):  # applied when the law runs
                    raise ConfigRangeError(f"{self.joint}.impedance", value, 0, 0)
        elif index in (Index.MAX_TORQUE, Index.MAX_CURRENT):
            other = Index.MAX_CURRENT if index == Index.MAX_TORQUE else Index.MAX_TORQUE
            per_mille = min(int(value), int(self.node.value(other)))
            self.axis.set_current_limit(self.joint, per_mille * self.scaling.amps_per_mille)
        elif index == Index.SOFTWARE_POSITION_LIMIT and not self.torque_axis:
            lo = int(self.node.value(Index.SOFTWARE_POSITION_LIMIT, 1)) if sub == 2 else int(value)
            hi = int(self.node.value(Index.SOFTWARE_POSITION_LIMIT, 2)) if sub == 1 else int(value)
            self.axis.set_position_limits(self.joint, self.scaling.position(lo), self.scaling.position(hi))  # type: ignore[union-attr]
