"""What each device of the simulated robot does: the glue between its CANopen node and the
simulator (``firmware_sim.simulator.Simulator``).

One ``NodeApplication`` per device type. Raw bus values are converted with the scales in
``protocol.can.objects``; configuration goes to the firmware boards, whose range and state
errors become SDO aborts; telemetry is sampled from the simulator after each physics step.
Reads of stiffness, damping and current limit are live (what the firmware really runs).
"""
from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from canopen.sdo import SdoAbortedError

from firmware_sim.controllers import ConfigRangeError, ConfigStateError, JointController
from firmware_sim.plant import AXES, ImuSample
from firmware_sim.nodes.base import Key, NodeApplication
from firmware_sim.simulator import Simulator
from protocol.can import objects as o
from protocol.can.devices import Device
from protocol.can.objects import Control, Index, Status
from protocol.can.sdo import AbortCode


_ACTUAL_VALUES = frozenset({Index.POSITION, Index.VELOCITY, Index.CURRENT, Index.VOLTAGE, Index.PITCH,
                            Index.PITCH_RATE, Index.PITCH_ACCELERATION, Index.ACCELERATION_X,
                            Index.ACCELERATION_Z})

_STATUS_BITS = (Status.OPERATION_ENABLED, Status.SAFE_STATE, Status.OVER_CURRENT, Status.CURRENT_LIMITING,
                Status.POSITION_LIMIT, Status.SPLINE_ACTIVE, Status.SPLINE_DONE, Status.CABLE_BROKEN)
"""The status-word bit of each board flag, in ``AxisStatus`` field order (``Simulator.axis_flags``)."""
_WORD_OF = np.array([sum(int(bit) for k, bit in enumerate(_STATUS_BITS) if packed >> k & 1)
                     for packed in range(1 << len(_STATUS_BITS))], dtype=np.int64)
"""Status-word bits of an axis by its flags packed into a byte (bit k = flag k)."""
_SAFE_FAULT = int(Status.SAFE_STATE | Status.FAULT)
_FAULTS = int(Status.OVER_CURRENT | Status.CABLE_BROKEN)
_FAULT, _ENABLED, _FALLEN = int(Status.FAULT), int(Status.OPERATION_ENABLED), int(Status.FALLEN)
_AXIS_INDEXES = (Index.POSITION, Index.VELOCITY, Index.CURRENT, Index.VOLTAGE)
_AXIS_SCALES = tuple(tuple(scale if index != Index.POSITION else (o.WHEEL_POSITION if a < 2 else o.POSITION)
                           for a in range(len(AXES)))
                     for index, scale in zip(_AXIS_INDEXES, (None, o.VELOCITY, o.CURRENT, o.VOLTAGE)))
"""Scale of each axis telemetry object, shape (4, 7): rows ``_AXIS_INDEXES``, columns ``AXES``
(the wheels' position is a 32-bit count)."""
CountScale = tuple[float, int, int]
"""A ``Scale`` as ``count`` uses it: (factor, raw_min, raw_max)."""
_AXIS_COUNT_SCALES: tuple[CountScale, ...] = tuple((s.factor, s.raw_min, s.raw_max)
                                                   for row in _AXIS_SCALES for s in row)
"""``_AXIS_SCALES`` row-major, 28 entries."""

SCENARIO_NAMES = {o.Scenario.IDLE: "idle", o.Scenario.BRACING: "bracing", o.Scenario.LIFTING: "lifting"}


def _raw(scale: o.Scale, value: float, missing: int = 0) -> int:
    return missing if math.isnan(value) else scale.to_raw(value)


_IMU_INDEXES = (Index.PITCH, Index.PITCH_RATE, Index.PITCH_ACCELERATION, Index.ACCELERATION_X,
                Index.ACCELERATION_Z)
_IMU_SCALES = (o.PITCH, o.PITCH_RATE, o.PITCH_ACCELERATION, o.ACCELERATION, o.ACCELERATION)
_IMU_COUNT_SCALES: tuple[CountScale, ...] = tuple((s.factor, s.raw_min, s.raw_max) for s in _IMU_SCALES)
IMU_SLOT = len(_AXIS_INDEXES) * len(AXES)
"""Where the IMU's counts start in a telemetry row (after the axes' counts)."""
STATUS_SLOT = IMU_SLOT + len(_IMU_INDEXES)
"""The slot of a telemetry row that holds the sampling device's status word (the last)."""


def axis_slot(index: int, axis: int) -> int:
    """Slot of an axis telemetry object (``index`` in ``_AXIS_INDEXES``) of axis number
    ``axis`` in a telemetry row."""
    return _AXIS_INDEXES.index(index) * len(AXES) + axis


@dataclass(frozen=True)
class AxisCounts:
    """Raw telemetry of every axis at one instant, what the boards' TPDOs carry.

    Attributes:
        values: position, velocity, current and voltage counts (``Scale.to_raw`` of each
            value), 28 ints: shape (4, 7) row-major, rows ``_AXIS_INDEXES``, columns ``AXES``
            (``axis_slot`` gives the place of one).
        words: status-word bits of each axis's board flags, 7 ints (a board ORs its axes').
    """
    values: list[int]
    words: tuple[int, ...]

    @classmethod
    def sample(cls, sim: Simulator, values: list[int] | None = None) -> "AxisCounts":
        """From the simulator's present state (``values``: its axis counts when already
        computed since the last step; the status words always now). ``ValueError`` on a NaN
        (as ``Scale.to_raw``)."""
        return cls(axis_counts(sim.axis_values()) if values is None else values, _WORDS.of(sim.axis_flags()))


def counts(values: Iterable[float], scales: Iterable[CountScale]) -> list[int]:
    """``Scale.to_raw`` of each value by its scale, bit for bit (the same division, the same
    saturation, ``round``); ``ValueError`` on a NaN like it."""
    out: list[int] = []
    append = out.append
    for value, (factor, low, high) in zip(values, scales):
        scaled = value / factor
        append(high if scaled >= high else low if scaled <= low else round(scaled))  # NaN: round raises
    return out


def axis_counts(values: Sequence[float]) -> list[int]:
    """``Scale.to_raw`` of every axis value: ``values`` 28 floats, SI units, shape (4, 7)
    row-major (rows ``_AXIS_INDEXES``, columns ``AXES``, as ``Simulator.axis_values``);
    returned in the same order."""
    return counts(values, _AXIS_COUNT_SCALES)


class _WordTable:
    """Status-word bits of each axis by the boards' flags (``Simulator.axis_flags``, shape
    (8, 7) bool), remembered by the flags' bytes: they change seldom (enable, limits, faults)."""

    LIMIT = 4096
    """Distinct flag states kept (the table starts afresh beyond)."""

    def __init__(self) -> None:
        self._words: dict[bytes, tuple[int, ...]] = {}

    def of(self, flags: np.ndarray) -> tuple[int, ...]:
        key = flags.tobytes()
        words = self._words.get(key)
        if words is None:
            if len(self._words) >= self.LIMIT:
                self._words.clear()
            packed = np.packbits(flags, axis=0, bitorder="little")[0]
            words = self._words[key] = tuple(_WORD_OF[packed].tolist())
        return words


_WORDS = _WordTable()


def telemetry_row(axes: AxisCounts, imu: ImuSample) -> list[int]:
    """Every telemetry count of the robot at one instant: the axes' counts, the IMU's
    (``_IMU_INDEXES`` order, from ``IMU_SLOT``) and a slot for a status word (``STATUS_SLOT``,
    0 here; the sampling device writes its own), 34 ints."""
    return [*axes.values, *counts((imu.pitch, imu.pitch_rate, imu.pitch_acc, imu.acc_x, imu.acc_z),
                                  _IMU_COUNT_SCALES), 0]


class Host(Protocol):
    """What a device application needs from the simulated robot it runs on (``SimulatedRobot``)."""

    sim: Simulator
    """The plant: physics, firmware boards and scenario, stepped one control period at a time."""
    lock: threading.RLock
    """Held around every access to ``sim`` (the physics step runs under it)."""

    def reset(self, scenario: str, seed: int) -> None:
        """Start an episode of ``scenario``: physics and every node back to their defaults."""

    def axis_counts(self) -> AxisCounts:
        """The raw axis telemetry of the present state (computed once per SYNC for all nodes)."""

    def telemetry(self) -> list[int]:
        """The robot's telemetry row of the present state (``telemetry_row``)."""


class DeviceApp(NodeApplication):
    """Common behaviour: enable with NMT OPERATIONAL + control word ENABLE, safe state on
    heartbeat loss, fault reset, status word."""

    def __init__(self, host: Host, device: Device) -> None:
        self.host, self.device = host, device
        self._axis_idx = [AXES.index(j) for j in device.joints]
        self.slots: dict[Key, int] = {(Index.STATUS, 0): STATUS_SLOT, **{
            (index, sub): axis_slot(index, axis) for index in _AXIS_INDEXES
            for sub, axis in enumerate(self._axis_idx, start=1)}}
        """Slot in the telemetry row (``telemetry_row``) of every object the device samples."""
        self.control = Control(0)
        self.safe = False
        self.operational = False

    @property
    def board(self):
        return self.host.sim.controller(self.device.name) if self.device.joints else None

    def _update_enable(self) -> None:
        if self.board is not None:
            self.board.set_enabled(self.operational and bool(self.control & Control.ENABLE))

    def on_nmt_state(self, state: str) -> None:
        with self.host.lock:
            self.operational = state == "OPERATIONAL"
            self._update_enable()

    def on_heartbeat_lost(self) -> None:
        with self.host.lock:
            self.safe = True
            if self.board is not None:
                self.board.enter_safe_state("agent heartbeat lost")

    def on_reset(self) -> None:
        self.control, self.safe = Control(0), False

    def on_commands(self, changed: dict[Key, int]) -> None:
        word = changed.get((Index.CONTROL, 0))
        if word is not None:
            self._on_control(Control(word & 0x7))

    def _on_control(self, word: Control) -> None:
        rising = word & ~self.control
        self.control = word
        if rising & Control.FAULT_RESET:
            self.safe = False
            if self.board is not None:
                self.board.clear_faults()
        self._update_enable()

    def status(self) -> Status:
        return Status(self.status_word(self.host.axis_counts() if self.device.joints else None))

    def status_word(self, axes: AxisCounts | None) -> int:
        """The status word: safe state and fault, else the board's flags OR-ed over its axes
        (``axes``; devices without axes report operation enabled while operational)."""
        s = _SAFE_FAULT if self.safe else 0
        if not self._axis_idx:
            return s | (_ENABLED if self.operational and not self.safe else 0)
        words = axes.words
        for i in self._axis_idx:
            s |= words[i]
        return s | _FAULT if s & _FAULTS else s

    def sample(self) -> None:
        """The device's telemetry (``slots``) of the present state into the node's values
        (what an SDO upload of a telemetry object reads)."""
        row = self.host.telemetry()
        row[STATUS_SLOT] = self.status_word(self.host.axis_counts() if self._axis_idx else None)
        self.node.values.update((key, row[slot]) for key, slot in self.slots.items())

    def on_config(self, key: Key, value) -> None:
        try:
            with self.host.lock:
                self.configure(key, value)
        except ConfigRangeError as exc:
            raise SdoAbortedError(AbortCode.VALUE_RANGE) from exc
        except ConfigStateError as exc:
            raise SdoAbortedError(AbortCode.DEVICE_STATE) from exc

    def configure(self, key: Key, value) -> None:
        index, sub = key
        if index == Index.CURRENT_LIMIT and self.board is not None:
            self.board.set_current_limit(self.device.joints[sub - 1], o.CURRENT_LIMIT.from_raw(value))

    def read(self, key: Key) -> int | None:
        index, sub = key
        if index == Index.STATUS:
            with self.host.lock:
                return int(self.status())
        if index in _ACTUAL_VALUES:  # a drive answers with the present value, not the last TPDO
            with self.host.lock:
                self.sample()
            return None
        if index == Index.CURRENT_LIMIT and self.board is not None and sub:
            return o.CURRENT_LIMIT.to_raw(self.board.current_limit(self.device.joints[sub - 1]))
        return None


_TORQUE_LEFT, _TORQUE_RIGHT = (Index.TORQUE_COMMAND, 1), (Index.TORQUE_COMMAND, 2)


def _wheel_torque(raw: int) -> float:
    """N m of a torque-command count, clamped to the wheel drivers' +-20 N m."""
    return max(-20.0, min(20.0, o.TORQUE.from_raw(raw)))


class WheelsApp(DeviceApp):
    def on_commands(self, changed: dict[Key, int]) -> None:
        super().on_commands(changed)
        if _TORQUE_LEFT in changed or _TORQUE_RIGHT in changed:
            value = self.node.value
            self.host.sim.set_wheel_torque(_wheel_torque(int(value(*_TORQUE_LEFT))),
                                           _wheel_torque(int(value(*_TORQUE_RIGHT))))



class JointApp(DeviceApp):
    """Torso and arm boards: impedance around setpoints, on-board spline tracking."""

    @property
    def board(self) -> JointController:
        return self.host.sim.controller(self.device.name)

    def on_commands(self, changed: dict[Key, int]) -> None:
        """Control word first (enabling holds the present pose), then the setpoints of the
        same RPDO, then a spline start: a setpoint sent with the first ENABLE takes effect."""
        word = changed.get((Index.CONTROL, 0))
        start = enabling = False
        if word is not None:
            rising = Control(word) & ~self.control
            start, enabling = bool(rising & Control.START_SPLINE), bool(rising & Control.ENABLE)
            self._on_control(Control(word & 0x7))
        if enabling:  # the setpoints received with (or before) the enabling RPDO apply now
            for sub in range(1, len(self.device.joints) + 1):
                raw = self.node.received(Index.POSITION_SETPOINT, sub)
                if raw is not None:
                    changed = {**changed, (Index.POSITION_SETPOINT, sub): raw}
        for (index, sub), raw in changed.items():
            if index == Index.POSITION_SETPOINT:
                self.board.set_setpoint(self.device.joints[sub - 1], o.POSITION.from_raw(raw))
        if start:
            try:
                self.board.start_spline()
            except ConfigStateError:
                pass  # SPLINE_ACTIVE never rises in the status word; the agent checks it

    def configure(self, key: Key, value) -> None:
        index, sub = key
        joints = self.device.joints
        if index in (Index.STIFFNESS, Index.DAMPING):
            k, d = self.board.impedance(joints[sub - 1])
            if index == Index.STIFFNESS:
                k = o.STIFFNESS.from_raw(value)
            else:
                d = o.DAMPING.from_raw(value)
            self.board.set_impedance(joints[sub - 1], k, d)
        elif index in (Index.POSITION_LIMIT_MIN, Index.POSITION_LIMIT_MAX):
            lo = o.POSITION.from_raw(int(self.node.value(Index.POSITION_LIMIT_MIN, sub)))
            hi = o.POSITION.from_raw(int(self.node.value(Index.POSITION_LIMIT_MAX, sub)))
            if index == Index.POSITION_LIMIT_MIN:
                lo = o.POSITION.from_raw(value)
            else:
                hi = o.POSITION.from_raw(value)
            self.board.set_position_limits(joints[sub - 1], lo, hi)
        elif index == Index.VELOCITY_LIMIT:
            self.board.set_velocity_limit(joints[sub - 1], o.VELOCITY_LIMIT.from_raw(value))
        elif index == Index.SPLINE_KNOT_COUNT and value:
            self._load_spline(int(value))
        else:
            super().configure(key, value)

    def _load_spline(self, n: int) -> None:
        """Writing the knot count (last) loads the knots downloaded before into the board."""
        if n < 2:
            raise ConfigRangeError("spline.knots", n, 2, o.SPLINE_MAX_KNOTS)
        v = self.node.value
        times = [o.KNOT_TIME.from_raw(int(v(Index.SPLINE_KNOT_TIME, k))) for k in range(1, n + 1)]
        axes = range(1, len(self.device.joints) + 1)
        pos = [[o.POSITION.from_raw(int(v(o.spline_position_index(a), k))) for a in axes] for k in range(1, n + 1)]
        vel = [[o.VELOCITY.from_raw(int(v(o.spline_velocity_index(a), k))) for a in axes] for k in range(1, n + 1)]
        try:
            self.board.load_spline(times, pos, vel)
        except ValueError as exc:  # non-increasing times etc.
            raise ConfigRangeError("spline", n, 2, o.SPLINE_MAX_KNOTS) from exc

    def read(self, key: Key) -> int | None:
        index, sub = key
        if index in (Index.STIFFNESS, Index.DAMPING) and sub:
            k, d = self.board.impedance(self.device.joints[sub - 1])
            return o.STIFFNESS.to_raw(k) if index == Index.STIFFNESS else o.DAMPING.to_raw(d)
        return super().read(key)


class ImuApp(DeviceApp):
    def status_word(self, axes: AxisCounts | None) -> int:
        return super().status_word(axes) | (_FALLEN if self.host.sim.fallen else 0)

    def __init__(self, host: Host, device: Device) -> None:
        super().__init__(host, device)
        self.slots.update({(index, 0): IMU_SLOT + k for k, index in enumerate(_IMU_INDEXES)})


class TestBenchApp(DeviceApp):
    """Scenario, seed, reset, impact trigger and ground truth (simulated benches only)."""

    def configure(self, key: Key, value) -> None:
        index, _ = key
        if index == Index.RESET and value == 1:
            scenario = o.Scenario(int(self.node.value(Index.SCENARIO)))
            self.host.reset(SCENARIO_NAMES[scenario], int(self.node.value(Index.SEED)))
        elif index == Index.IMPACT_TRIGGER and value == 1:
            if self.host.sim.scenario != "bracing":
                raise ConfigStateError("impact trigger outside the bracing scenario")
            self.host.sim.trigger_impact()
        elif index == Index.BALANCE_FREE:
            self.host.sim.balance_free = bool(value)

    def read(self, key: Key) -> int | None:
        index, sub = key
        if index == Index.STATUS:
            return super().read(key)
        with self.host.lock:
            t = self.host.sim.truth
        if index == Index.IMPACT_MOMENTUM:
            return _raw(o.MOMENTUM, t.impact_momentum)
        if index == Index.CABLE_TENSION and sub:
            return o.TENSION.to_raw((t.cable_tension_left, t.cable_tension_right)[sub - 1])
        if index == Index.BOTTLE_HEIGHT:
            return _raw(o.HEIGHT, t.bottle_height, missing=o.HEIGHT.raw_min)
        if index == Index.BOTTLE_COM_HEIGHT:
            return _raw(o.HEIGHT, t.bottle_com[2], missing=o.HEIGHT.raw_min)
        if index == Index.SIM_TIME:
            return o.SIM_TIME.to_raw(t.sim_time)
        if index == Index.GROUND_TRUTH_FLAGS:
            return int((Status.FALLEN if t.fallen else Status(0)) | (Status.CABLE_BROKEN if t.damaged else Status(0))
                       | (Status.BOTTLE_DROPPED if t.bottle_dropped else Status(0)))
        return None


APPS = {"wheels": WheelsApp, "torso": JointApp, "arm_left": JointApp, "arm_right": JointApp,
        "imu": ImuApp, "testbench": TestBenchApp}
