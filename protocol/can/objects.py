"""Named object-dictionary entries, their scaling, and the bit/code tables of the devices.

Raw values on the bus are integers; ``Scale`` converts between SI units and counts.
``to_raw`` saturates at the integer type's range (a sensor that saturates reports its limit,
it does not wrap around); the saturation is documented per signal in docs/protocol.md.
"""
from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass, replace


class Index(enum.IntEnum):
    """Object indexes (CiA 301 communication area and the devices' manufacturer area)."""
    DEVICE_TYPE = 0x1000
    ERROR_REGISTER = 0x1001
    COB_ID_SYNC = 0x1005
    DEVICE_NAME = 0x1008
    COB_ID_EMCY = 0x1014
    CONSUMER_HEARTBEAT = 0x1016
    PRODUCER_HEARTBEAT = 0x1017
    IDENTITY = 0x1018
    # axes (ARRAY, sub-index = axis number)
    POSITION = 0x2000
    VELOCITY = 0x2001
    CURRENT = 0x2002
    VOLTAGE = 0x2003
    STATUS = 0x2010
    CONTROL = 0x2011
    TORQUE_COMMAND = 0x2020
    POSITION_SETPOINT = 0x2021
    STIFFNESS = 0x2030
    DAMPING = 0x2031
    POSITION_LIMIT_MIN = 0x2032
    POSITION_LIMIT_MAX = 0x2033
    CURRENT_LIMIT = 0x2034
    VELOCITY_LIMIT = 0x2035
    # arm spline (ARRAY of 8 knots; positions/velocities per axis at 0x2042 + 2 * (axis - 1))
    SPLINE_KNOT_COUNT = 0x2040
    SPLINE_KNOT_TIME = 0x2041
    SPLINE_POSITION = 0x2042
    SPLINE_VELOCITY = 0x2043
    # IMU
    PITCH = 0x2100
    PITCH_RATE = 0x2101
    PITCH_ACCELERATION = 0x2102
    ACCELERATION_X = 0x2103
    ACCELERATION_Z = 0x2104
    # test bench (simulated benches only)
    SCENARIO = 0x3000
    SEED = 0x3001
    RESET = 0x3002
    IMPACT_TRIGGER = 0x3003
    IMPACT_MOMENTUM = 0x3004
    CABLE_TENSION = 0x3005
    BOTTLE_HEIGHT = 0x3006
    SIM_TIME = 0x3007
    GROUND_TRUTH_FLAGS = 0x3008
    BALANCE_FREE = 0x3009
    BOTTLE_COM_HEIGHT = 0x300A


SPLINE_MAX_KNOTS = 8


def spline_position_index(axis: int) -> int:
    """Index of the knot-position array of arm axis ``axis`` (1 = shoulder, 2 = elbow)."""
    return Index.SPLINE_POSITION + 2 * (axis - 1)


def spline_velocity_index(axis: int) -> int:
    return Index.SPLINE_VELOCITY + 2 * (axis - 1)


class Scenario(enum.IntEnum):
    IDLE = 0
    BRACING = 1
    LIFTING = 2


class DataType(enum.IntEnum):
    """CiA 301 data type codes (EDS ``DataType``)."""
    BOOLEAN = 0x0001
    INT8 = 0x0002
    INT16 = 0x0003
    INT32 = 0x0004
    UINT8 = 0x0005
    UINT16 = 0x0006
    UINT32 = 0x0007
    REAL32 = 0x0008
    VISIBLE_STRING = 0x0009

    @property
    def bits(self) -> int:
        return {DataType.BOOLEAN: 1, DataType.INT8: 8, DataType.UINT8: 8, DataType.INT16: 16,
                DataType.UINT16: 16, DataType.INT32: 32, DataType.UINT32: 32,
                DataType.REAL32: 32}[self]

    @property
    def signed(self) -> bool:
        return self in (DataType.INT8, DataType.INT16, DataType.INT32)


@dataclass(frozen=True)
class Scale:
    """``value_SI = raw * factor``. ``bits``/``signed`` give the integer range for saturation."""
    factor: float
    unit: str
    bits: int = 16
    signed: bool = True

    @functools.cached_property
    def raw_min(self) -> int:
        return -(1 << (self.bits - 1)) if self.signed else 0

    @functools.cached_property
    def raw_max(self) -> int:
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1

    def to_raw(self, value: float) -> int:
        """SI value -> saturated integer count. NaN is refused (ValueError)."""
        if math.isnan(value):
            raise ValueError("cannot encode NaN")
        scaled = value / self.factor
        if scaled >= self.raw_max:
            return self.raw_max
        if scaled <= self.raw_min:
            return self.raw_min
        return round(scaled)

    def from_raw(self, raw: int) -> float:
        return raw * self.factor


@dataclass(frozen=True)
class ObjectSpec:
    """One manufacturer object as every device that has it agrees on it.

    ``low``/``high`` are raw limits (EDS ``LowLimit``/``HighLimit``); ``factor``/``unit`` the
    scaling (EDS ``Factor``/``Unit``: ``value_SI = raw * factor``), or ``meaning`` for values
    that are codes or bits (EDS ``Description``). Which devices have an object, as VAR or as
    an ARRAY over their axes, and with which default, is in each device's EDS file.
    """
    index: int
    name: str
    dtype: DataType
    access: str = "rw"
    pdo: bool = False
    low: int | None = None
    high: int | None = None
    factor: float | None = None
    unit: str = ""
    meaning: str = ""

    @property
    def scale(self) -> Scale:
        if self.factor is None:
            raise ValueError(f"object 0x{self.index:04X} ({self.name}) has no scaling")
        return Scale(self.factor, self.unit, self.dtype.bits, self.dtype.signed)

    @property
    def limits(self) -> tuple[float, float]:
        """(low, high) in SI units (both limits must be set)."""
        if self.low is None or self.high is None:
            raise ValueError(f"object 0x{self.index:04X} ({self.name}) has no range")
        return self.scale.from_raw(self.low), self.scale.from_raw(self.high)

    def at(self, index: int, name: str) -> "ObjectSpec":
        """The same kind of object at another index (per-axis spline arrays)."""
        return replace(self, index=index, name=name)


_T = DataType
_PI_1E4 = 31416  # +-pi in 1e-4 rad
OBJECTS: dict[int, ObjectSpec] = {o.index: o for o in (
    ObjectSpec(Index.POSITION, "Position actual", _T.INT16, "ro", True, factor=1e-4, unit="rad"),
    ObjectSpec(Index.VELOCITY, "Velocity actual", _T.INT16, "ro", True, factor=1e-3, unit="rad/s"),
    ObjectSpec(Index.CURRENT, "Motor current", _T.INT16, "ro", True, factor=1e-3, unit="A"),
    ObjectSpec(Index.VOLTAGE, "Motor voltage", _T.INT16, "ro", True, factor=1e-3, unit="V"),
    ObjectSpec(Index.STATUS, "Status word", _T.UINT16, "ro", True, meaning="status bits"),
    ObjectSpec(Index.CONTROL, "Control word", _T.UINT16, "rw", True, meaning="control bits"),
    ObjectSpec(Index.TORQUE_COMMAND, "Torque command", _T.INT16, "rw", True, -20000, 20000, 1e-3, "N m"),
    ObjectSpec(Index.POSITION_SETPOINT, "Position setpoint", _T.INT16, "rw", True, -_PI_1E4, _PI_1E4,
               1e-4, "rad"),
    ObjectSpec(Index.STIFFNESS, "Joint stiffness", _T.UINT16, "rw", False, 0, 50000, 1e-2, "N m/rad"),
    ObjectSpec(Index.DAMPING, "Joint damping", _T.UINT16, "rw", False, 0, 50000, 1e-3, "N m s/rad"),
    ObjectSpec(Index.POSITION_LIMIT_MIN, "Position limit min", _T.INT16, "rw", False, -_PI_1E4, _PI_1E4,
               1e-4, "rad"),
    ObjectSpec(Index.POSITION_LIMIT_MAX, "Position limit max", _T.INT16, "rw", False, -_PI_1E4, _PI_1E4,
               1e-4, "rad"),
    ObjectSpec(Index.CURRENT_LIMIT, "Current limit", _T.UINT16, "rw", False, 0, 30000, 1e-3, "A"),
    ObjectSpec(Index.VELOCITY_LIMIT, "Velocity limit", _T.UINT16, "rw", False, 0, 30000, 1e-3, "rad/s"),
    ObjectSpec(Index.SPLINE_KNOT_COUNT, "Spline knot count", _T.UINT8, "rw", False, 0, SPLINE_MAX_KNOTS,
               meaning="knots (writing it loads the spline)"),
    ObjectSpec(Index.SPLINE_KNOT_TIME, "Spline knot time", _T.UINT16, "rw", False, 0, 60000, 1e-3, "s"),
    ObjectSpec(Index.SPLINE_POSITION, "Spline position", _T.INT16, "rw", False, -_PI_1E4, _PI_1E4,
               1e-4, "rad"),
    ObjectSpec(Index.SPLINE_VELOCITY, "Spline velocity", _T.INT16, "rw", False, -30000, 30000, 1e-3, "rad/s"),
    ObjectSpec(Index.PITCH, "Pitch", _T.INT16, "ro", True, factor=1e-4, unit="rad"),
    ObjectSpec(Index.PITCH_RATE, "Pitch rate", _T.INT16, "ro", True, factor=1e-3, unit="rad/s"),
    ObjectSpec(Index.PITCH_ACCELERATION, "Pitch acceleration", _T.INT16, "ro", True, factor=0.1,
               unit="rad/s^2"),
    ObjectSpec(Index.ACCELERATION_X, "Acceleration x", _T.INT16, "ro", True, factor=0.01, unit="m/s^2"),
    ObjectSpec(Index.ACCELERATION_Z, "Acceleration z", _T.INT16, "ro", True, factor=0.01, unit="m/s^2"),
    ObjectSpec(Index.SCENARIO, "Scenario", _T.UINT8, "rw", False, min(Scenario), max(Scenario),
               meaning=", ".join(f"{s.value} {s.name.lower()}" for s in Scenario)),
    ObjectSpec(Index.SEED, "Seed", _T.UINT32, "rw", meaning="random seed of the next reset"),
    ObjectSpec(Index.RESET, "Reset", _T.UINT8, "rw", False, 0, 1, meaning="write 1: reset scenario"),
    ObjectSpec(Index.IMPACT_TRIGGER, "Impact trigger", _T.UINT8, "rw", False, 0, 1,
               meaning="write 1: release pendulum"),
    ObjectSpec(Index.IMPACT_MOMENTUM, "Impact momentum", _T.UINT16, "ro", factor=0.01, unit="N s"),
    ObjectSpec(Index.CABLE_TENSION, "Cable tension", _T.UINT16, "ro", factor=0.1, unit="N"),
    ObjectSpec(Index.BOTTLE_HEIGHT, "Bottle height", _T.INT16, "ro", factor=1e-3, unit="m"),
    ObjectSpec(Index.SIM_TIME, "Simulated time", _T.UINT32, "ro", factor=1e-6, unit="s"),
    ObjectSpec(Index.GROUND_TRUTH_FLAGS, "Ground truth flags", _T.UINT16, "ro", meaning="status bits"),
    ObjectSpec(Index.BALANCE_FREE, "Balance free", _T.UINT8, "rw", False, 0, 1,
               meaning="1: wheels passive"),
    ObjectSpec(Index.BOTTLE_COM_HEIGHT, "Bottle COM height", _T.INT16, "ro", factor=1e-3, unit="m"),
)}
"""Every manufacturer object by index: the one source of its name, data type,
access, PDO mappability, raw limits and scaling. ``tools/gen_eds.py`` writes the EDS files from
it; agent and simulator scale with the ``Scale`` constants below, taken from it."""

WHEEL_POSITION_OBJECT = replace(OBJECTS[Index.POSITION], dtype=DataType.INT32)
"""The wheel controller reports its positions in 32 bits (a wheel turns without end)."""

POSITION = OBJECTS[Index.POSITION].scale
WHEEL_POSITION = WHEEL_POSITION_OBJECT.scale
VELOCITY = OBJECTS[Index.VELOCITY].scale
CURRENT = OBJECTS[Index.CURRENT].scale
VOLTAGE = OBJECTS[Index.VOLTAGE].scale
TORQUE = OBJECTS[Index.TORQUE_COMMAND].scale
STIFFNESS = OBJECTS[Index.STIFFNESS].scale
DAMPING = OBJECTS[Index.DAMPING].scale
CURRENT_LIMIT = OBJECTS[Index.CURRENT_LIMIT].scale
VELOCITY_LIMIT = OBJECTS[Index.VELOCITY_LIMIT].scale
KNOT_TIME = OBJECTS[Index.SPLINE_KNOT_TIME].scale
PITCH = OBJECTS[Index.PITCH].scale
PITCH_RATE = OBJECTS[Index.PITCH_RATE].scale
PITCH_ACCELERATION = OBJECTS[Index.PITCH_ACCELERATION].scale
ACCELERATION = OBJECTS[Index.ACCELERATION_X].scale
MOMENTUM = OBJECTS[Index.IMPACT_MOMENTUM].scale
TENSION = OBJECTS[Index.CABLE_TENSION].scale
HEIGHT = OBJECTS[Index.BOTTLE_HEIGHT].scale
SIM_TIME = OBJECTS[Index.SIM_TIME].scale


class Status(enum.IntFlag):
    """Status word 0x2010 (every device). Sampled at SYNC into the device's last TPDO."""
    OPERATION_ENABLED = 1 << 0
    FAULT = 1 << 1
    OVER_CURRENT = 1 << 2
    CABLE_BROKEN = 1 << 3      # arm: elbow cable snapped (hardware damage)
    FALLEN = 1 << 4            # IMU / test bench: body pitch beyond the fall threshold
    BOTTLE_DROPPED = 1 << 5    # arm / test bench: grasp lost
    SAFE_STATE = 1 << 6        # heartbeat of the agent lost: zero torque
    SPLINE_ACTIVE = 1 << 7
    SPLINE_DONE = 1 << 8
    CURRENT_LIMITING = 1 << 9
    POSITION_LIMIT = 1 << 10


class Control(enum.IntFlag):
    """Control word 0x2011 (actuated devices), received in RPDO1."""
    ENABLE = 1 << 0
    START_SPLINE = 1 << 1      # rising edge starts the downloaded spline
    FAULT_RESET = 1 << 2


class EmcyCode(enum.IntEnum):
    """EMCY error codes (CiA 301 generic codes, 0xFFxx manufacturer-specific)."""
    NO_ERROR = 0x0000
    OVER_CURRENT = 0x2310      # continuous over-current
    HEARTBEAT_LOST = 0x8130    # life guard / heartbeat error: controller entered safe state
    CABLE_BROKEN = 0xFF10      # elbow cable tension above its limit: hardware damaged
    FALLEN = 0xFF20
    BOTTLE_DROPPED = 0xFF30


class ErrorRegister(enum.IntFlag):
    """Object 0x1001 bits, sent as byte 2 of every EMCY."""
    GENERIC = 1 << 0
    CURRENT = 1 << 1
    COMMUNICATION = 1 << 4
    MANUFACTURER = 1 << 7


EMCY_REGISTER = {
    EmcyCode.NO_ERROR: ErrorRegister(0),
    EmcyCode.OVER_CURRENT: ErrorRegister.GENERIC | ErrorRegister.CURRENT,
    EmcyCode.HEARTBEAT_LOST: ErrorRegister.GENERIC | ErrorRegister.COMMUNICATION,
    EmcyCode.CABLE_BROKEN: ErrorRegister.GENERIC | ErrorRegister.MANUFACTURER,
    EmcyCode.FALLEN: ErrorRegister.GENERIC | ErrorRegister.MANUFACTURER,
    EmcyCode.BOTTLE_DROPPED: ErrorRegister.GENERIC | ErrorRegister.MANUFACTURER,
}
"""Error register value sent with each EMCY code."""
