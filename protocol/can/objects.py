"""Named object-dictionary entries, their scaling, and the bit/code tables of the bench.

Raw values on the bus are integers; ``Scale`` converts between SI units and counts.
``to_raw`` saturates at the integer type's range (a sensor that saturates reports its limit,
it does not wrap around); the saturation is documented per signal in docs/protocol.md.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class Index(enum.IntEnum):
    """Object indexes (CiA 301 communication area and the bench's manufacturer area)."""
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


@dataclass(frozen=True)
class Scale:
    """``value_SI = raw * factor``. ``bits``/``signed`` give the integer range for saturation."""
    factor: float
    unit: str
    bits: int = 16
    signed: bool = True

    @property
    def raw_min(self) -> int:
        return -(1 << (self.bits - 1)) if self.signed else 0

    @property
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


POSITION = Scale(1e-4, "rad")
WHEEL_POSITION = Scale(1e-4, "rad", bits=32)
VELOCITY = Scale(1e-3, "rad/s")
CURRENT = Scale(1e-3, "A")
VOLTAGE = Scale(1e-3, "V")
TORQUE = Scale(1e-3, "N m")
STIFFNESS = Scale(1e-2, "N m/rad", signed=False)
DAMPING = Scale(1e-3, "N m s/rad", signed=False)
CURRENT_LIMIT = Scale(1e-3, "A", signed=False)
VELOCITY_LIMIT = Scale(1e-3, "rad/s", signed=False)
KNOT_TIME = Scale(1e-3, "s", signed=False)
PITCH = Scale(1e-4, "rad")
PITCH_RATE = Scale(1e-3, "rad/s")
PITCH_ACCELERATION = Scale(0.1, "rad/s^2")
ACCELERATION = Scale(0.01, "m/s^2")
MOMENTUM = Scale(0.01, "N s", signed=False)
TENSION = Scale(0.1, "N", signed=False)
HEIGHT = Scale(1e-3, "m")
SIM_TIME = Scale(1e-6, "s", bits=32, signed=False)


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
