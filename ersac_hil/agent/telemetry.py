"""What goes over the bus each SYNC cycle, in SI units: ``Commands`` out, ``Telemetry`` in.

Both are frozen dataclasses; the CANopen encoding (counts, PDO layout) lives in ``bus.py``.
``Trace`` stacks the telemetry of an episode into arrays for the cost terms.

Joint order everywhere is ``JOINTS`` (the uBot's parts in ``layout.PARTS`` order):
``wheel_left, wheel_right, torso, shoulder_left, elbow_left, shoulder_right, elbow_right``;
which node and sub-index carries each, and which node takes which part's commands, is the robot
description's (``layout.RobotLayout``), never a table here.
"""
from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter, mul
from typing import Any

import numpy as np

from ersac_hil.agent.layout import JOINTS, PARTS, STATUS_PARTS, RobotLayout, default_layout
from protocol.can import objects as obj
from protocol.can.objects import Control, Index, Status
from protocol.can.pdo import PdoSpec, pdo_struct
from protocol.robot.model import Device

STATUS_DEVICES: tuple[str, ...] = STATUS_PARTS
"""What each status word of ``Telemetry.status`` is of: the uBot's parts, then the IMU (the
names of the default robot's boards)."""
ACTUATED: tuple[Device, ...] = default_layout().actuated
"""The default robot's nodes with motor axes (tests and benches on it; the agent's bus has the
layout of its own description, ``AgentBus.layout``)."""
CYCLIC: tuple[Device, ...] = default_layout().cyclic
"""The default robot's nodes with synchronous TPDOs."""


def _part_slice(part: str) -> slice:
    start = JOINTS.index(PARTS[part][0])
    return slice(start, start + len(PARTS[part]))


WHEELS_SLICE = _part_slice("wheels")
TORSO_I = JOINTS.index("torso")
ARM_SLICES = {"left": _part_slice("arm_left"), "right": _part_slice("arm_right")}

AXIS_SCALES = {Index.POSITION: obj.POSITION, Index.VELOCITY: obj.VELOCITY,
               Index.CURRENT: obj.CURRENT, Index.VOLTAGE: obj.VOLTAGE}
"""Per-axis telemetry objects and their scaling (wheel positions share the 1e-4 rad factor)."""
IMU_SCALES = {Index.PITCH: obj.PITCH, Index.PITCH_RATE: obj.PITCH_RATE,
              Index.PITCH_ACCELERATION: obj.PITCH_ACCELERATION,
              Index.ACCELERATION_X: obj.ACCELERATION, Index.ACCELERATION_Z: obj.ACCELERATION}


@dataclass(frozen=True)
class Commands:
    """Setpoints of one SYNC cycle (what the RPDOs carry).

    Attributes:
        wheel_torque: (left, right) motor torque at the wheel [N m], saturated at the
            16-bit range (+-32.767 N m); the controllers limit further.
        torso_position: torso yaw setpoint [rad].
        arm_left, arm_right: (shoulder, elbow) position setpoints [rad].
        control: control word for the wheels and torso.
        arm_control: control word for both arms (``START_SPLINE`` rising edge starts the
            downloaded spline).
    """
    wheel_torque: tuple[float, float] = (0.0, 0.0)
    torso_position: float = 0.0
    arm_left: tuple[float, float] = (0.0, 0.0)
    arm_right: tuple[float, float] = (0.0, 0.0)
    control: Control = Control.ENABLE
    arm_control: Control = Control.ENABLE

    def raw(self, part: str) -> dict[tuple[int, int], int]:
        """RPDO values of the uBot board of ``part`` (``layout.PARTS``) as raw counts by
        (index, sub-index)."""
        return _RAW_OF[part](*self.inputs(part))

    def inputs(self, part: str) -> tuple:
        """The fields the RPDOs of ``part``'s board carry (``raw`` is a function of them alone)."""
        if part == "wheels":
            return self.wheel_torque, self.control
        if part == "torso":
            return self.torso_position, self.control
        if part == "arm_left":
            return self.arm_left, self.arm_control
        if part == "arm_right":
            return self.arm_right, self.arm_control
        raise KeyError(f"{part} takes no commands")


def _wheels_raw(torque: tuple[float, float], control: Control) -> dict[tuple[int, int], int]:
    left, right = torque
    return {(Index.TORQUE_COMMAND, 1): obj.TORQUE.to_raw(left),
            (Index.TORQUE_COMMAND, 2): obj.TORQUE.to_raw(right),
            (Index.CONTROL, 0): int(control)}


def _torso_raw(position: float, control: Control) -> dict[tuple[int, int], int]:
    return {(Index.POSITION_SETPOINT, 1): obj.POSITION.to_raw(position), (Index.CONTROL, 0): int(control)}


def _arm_raw(pose: tuple[float, float], control: Control) -> dict[tuple[int, int], int]:
    shoulder, elbow = pose
    return {(Index.POSITION_SETPOINT, 1): obj.POSITION.to_raw(shoulder),
            (Index.POSITION_SETPOINT, 2): obj.POSITION.to_raw(elbow),
            (Index.CONTROL, 0): int(control)}


_RAW_OF = {"wheels": _wheels_raw, "torso": _torso_raw, "arm_left": _arm_raw, "arm_right": _arm_raw}


class CommandEncoder:
    """The RPDO frames of ``Commands``, compiled for one bus: per RPDO its struct and the
    (index, sub-index) of each field. A device's frames are re-encoded only when its
    ``Commands.inputs`` changed (the arms' and the torso's setpoints are the same cycle after
    cycle); the bytes are those of ``Commands.raw`` packed, always.

    Args:
        rpdos: per RPDO in sending order: (device name, COB-ID, struct, field keys).
        layout: which part each device is (default: the default robot's).
    """

    def __init__(self, rpdos: Sequence[tuple[str, int, Any, tuple[tuple[int, int], ...]]],
                 layout: RobotLayout | None = None) -> None:
        part_of = (layout or default_layout()).part_of
        self._devices: dict[str, list[tuple[int, Any, tuple[tuple[int, int], ...]]]] = {}
        for name, cob_id, pdo, keys in rpdos:
            self._devices.setdefault(part_of[name], []).append((cob_id, pdo, keys))
        self._last: dict[str, tuple[tuple, list[tuple[int, bytes]]]] = {}

    def encode(self, commands: Commands) -> list[tuple[int, bytes]]:
        """``(COB-ID, data)`` of every RPDO, devices in the order given."""
        frames: list[tuple[int, bytes]] = []
        for part, rpdos in self._devices.items():
            inputs = commands.inputs(part)
            last = self._last.get(part)
            if last is None or last[0] != inputs:
                raw = commands.raw(part)
                last = (inputs, [(cob_id, pdo.pack(*[raw[k] for k in keys])) for cob_id, pdo, keys in rpdos])
                self._last[part] = last
            frames += last[1]
        return frames


def mean2(a: float, b: float) -> float:
    """``float(np.mean((a, b)))`` to the bit without numpy's call overhead: the sum of two
    floats, never -0.0 (numpy adds to a +0.0), halved."""
    return (a + b + 0.0) / 2


@dataclass(frozen=True)
class Telemetry:
    """Everything the synchronous TPDOs of one SYNC cycle carried, in SI units.

    Attributes:
        cycle: SYNC count since the bus was opened (1 = first SYNC).
        position, velocity, current, voltage: per joint in ``JOINTS`` order, shape ``(7,)``
            [rad, rad/s, A, V].
        pitch, pitch_rate, pitch_acc: body pitch [rad] (positive leaning forward), its rate
            [rad/s] and acceleration [rad/s^2] from the IMU.
        acc_x, acc_z: IMU linear acceleration [m/s^2].
        status: status words in ``STATUS_DEVICES`` order.
        latency_s: wall time from SYNC to the last TPDO of the cycle.
    """
    cycle: int
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    current: tuple[float, ...]
    voltage: tuple[float, ...]
    pitch: float
    pitch_rate: float
    pitch_acc: float
    acc_x: float
    acc_z: float
    status: tuple[int, ...]
    latency_s: float = field(default=0.0, compare=False)

    @classmethod
    def decode(cls, cycle: int, raw: dict[str, dict[tuple[int, int], int]],
               latency_s: float = 0.0, layout: RobotLayout | None = None) -> "Telemetry":
        """From raw TPDO counts of the uBot boards by device name and (index, sub-index)
        (``layout``: the robot's, default the default robot's)."""
        layout = layout or default_layout()
        axes = {index: [0.0] * len(JOINTS) for index in AXIS_SCALES}
        for (name, sub), j in layout.joint_index.items():
            for index, scale in AXIS_SCALES.items():
                axes[index][j] = scale.from_raw(raw[name][(index, sub)])
        imu = raw[layout.imu.name]
        return cls(cycle=cycle,
                   position=tuple(axes[Index.POSITION]), velocity=tuple(axes[Index.VELOCITY]),
                   current=tuple(axes[Index.CURRENT]), voltage=tuple(axes[Index.VOLTAGE]),
                   **{name: IMU_SCALES[index].from_raw(imu[(index, 0)]) for name, index in (
                       ("pitch", Index.PITCH), ("pitch_rate", Index.PITCH_RATE),
                       ("pitch_acc", Index.PITCH_ACCELERATION), ("acc_x", Index.ACCELERATION_X),
                       ("acc_z", Index.ACCELERATION_Z))},
                   status=tuple(int(raw[layout.board(part).name][(Index.STATUS, 0)]) for part in STATUS_PARTS),
                   latency_s=latency_s)

    # -- named accessors ------------------------------------------------------------------
    @property
    def wheel_positions(self) -> tuple[float, float]:
        return self.position[WHEELS_SLICE]  # type: ignore[return-value]

    @property
    def wheel_velocities(self) -> tuple[float, float]:
        return self.velocity[WHEELS_SLICE]  # type: ignore[return-value]

    @property
    def wheel_position_mean(self) -> float:
        """Mean of the two wheel angles [rad], ``float(np.mean(wheel_positions))`` to the bit."""
        return mean2(*self.position[WHEELS_SLICE])

    @property
    def wheel_velocity_mean(self) -> float:
        """Mean of the two wheel velocities [rad/s], ``float(np.mean(wheel_velocities))`` to the bit."""
        return mean2(*self.velocity[WHEELS_SLICE])

    @property
    def torso_position(self) -> float:
        return self.position[TORSO_I]

    def arm_positions(self, side: str) -> tuple[float, float]:
        """(shoulder, elbow) [rad] of ``side`` ("left" or "right")."""
        return self.position[ARM_SLICES[side]]  # type: ignore[return-value]

    def arm_velocities(self, side: str) -> tuple[float, float]:
        return self.velocity[ARM_SLICES[side]]  # type: ignore[return-value]

    def status_of(self, device: str) -> Status:
        return Status(self.status[STATUS_DEVICES.index(device)])

    @property
    def status_bits(self) -> int:
        """OR of every device's status word as a plain int (the per-cycle check: no enum)."""
        out = 0
        for word in self.status:
            out |= word
        return out

    @property
    def any_status(self) -> Status:
        """OR of every device's status word."""
        return Status(self.status_bits)


class TelemetryDecoder:
    """``Telemetry.decode`` compiled for one set of TPDO maps: the data of the frames, joined
    in a fixed order, is unpacked by one struct and every value goes straight to its place in
    the telemetry, no dictionaries per cycle. Values are the same to the bit (the same integer
    fields, ``raw * factor`` as ``Scale.from_raw``).

    Args:
        tpdos: the synchronous TPDO maps (``protocol.can.pdo.PdoSpec``, any order); together
            they must carry every object ``Telemetry.decode`` reads.
        layout: the robot's (default: the default robot's).
    """

    def __init__(self, tpdos: Sequence[PdoSpec], layout: RobotLayout | None = None) -> None:
        layout = layout or default_layout()
        self.cob_ids = tuple(p.cob_id for p in tpdos)
        self._unpack = struct.Struct("<" + "".join(pdo_struct(p).format.lstrip("<") for p in tpdos)).unpack
        pick = itemgetter(*self.cob_ids)
        self._data: Callable[[Mapping[int, bytes | bytearray]], tuple] = (
            pick if len(self.cob_ids) > 1 else lambda frames: (pick(frames),))
        slot: dict[tuple[str, tuple[int, int]], int] = {}
        for p in tpdos:
            for key in p.keys:
                slot[(p.device, key)] = len(slot)
        by_joint = sorted((j, name, sub) for (name, sub), j in layout.joint_index.items())
        # the scaled values in telemetry order: 4 x 7 axis values (position, velocity, current,
        # voltage by joint), then the IMU's 5
        scaled = [(slot[(name, (index, sub))], scale.factor) for index, scale in AXIS_SCALES.items()
                  for _, name, sub in by_joint]
        scaled += [(slot[(layout.imu.name, (index, 0))], IMU_SCALES[index].factor) for index in (
            Index.PITCH, Index.PITCH_RATE, Index.PITCH_ACCELERATION, Index.ACCELERATION_X,
            Index.ACCELERATION_Z)]
        self._raw = itemgetter(*[i for i, _ in scaled])
        self._factors = tuple(f for _, f in scaled)
        self._status = itemgetter(*[slot[(layout.board(part).name, (Index.STATUS, 0))] for part in STATUS_PARTS])

    def decode(self, cycle: int, frames: Mapping[int, bytes | bytearray], latency_s: float = 0.0) -> Telemetry:
        """The telemetry of one SYNC from the data of each frame by COB-ID (every one present,
        each exactly its map's size)."""
        flat = self._unpack(b"".join(self._data(frames)))
        v = list(map(mul, self._raw(flat), self._factors))
        return Telemetry(cycle, tuple(v[0:7]), tuple(v[7:14]), tuple(v[14:21]), tuple(v[21:28]),
                         v[28], v[29], v[30], v[31], v[32], self._status(flat), latency_s)


@dataclass(frozen=True)
class Trace:
    """The telemetry of an episode stacked into arrays (``n`` cycles).

    Attributes:
        dt: control period [s] (time between samples).
        position, velocity, current, voltage: shape ``(n, 7)``, ``JOINTS`` order.
        pitch, pitch_rate, pitch_acc, acc_x, acc_z: shape ``(n,)``.
        status: shape ``(n, 5)`` status words, ``STATUS_DEVICES`` order.
    """
    dt: float
    position: np.ndarray
    velocity: np.ndarray
    current: np.ndarray
    voltage: np.ndarray
    pitch: np.ndarray
    pitch_rate: np.ndarray
    pitch_acc: np.ndarray
    acc_x: np.ndarray
    acc_z: np.ndarray
    status: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[Telemetry], dt: float) -> "Trace":
        n = len(samples)

        def col(name: str, width: int | None = None) -> np.ndarray:
            a = np.array([getattr(s, name) for s in samples], dtype=float)
            return a.reshape((n, width) if width else (n,))

        return cls(dt=dt,
                   position=col("position", len(JOINTS)), velocity=col("velocity", len(JOINTS)),
                   current=col("current", len(JOINTS)), voltage=col("voltage", len(JOINTS)),
                   pitch=col("pitch"), pitch_rate=col("pitch_rate"), pitch_acc=col("pitch_acc"),
                   acc_x=col("acc_x"), acc_z=col("acc_z"),
                   status=np.array([s.status for s in samples], dtype=np.int64).reshape(
                       n, len(STATUS_DEVICES)))

    def __len__(self) -> int:
        return int(self.pitch.shape[0])

    @property
    def duration_s(self) -> float:
        return len(self) * self.dt

    def joint(self, name: str) -> int:
        return JOINTS.index(name)

    def status_any(self) -> int:
        """OR of every status word of every cycle."""
        return int(np.bitwise_or.reduce(self.status, axis=None)) if len(self) else 0
