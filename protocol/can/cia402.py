"""CiA 402 (IEC 61800-7-201) servo drives: the profile's objects as the project's drive EDS
(``cia402_drive.eds``) has them, the power state machine's states and controlword commands,
modes of operation and quick-stop option codes.

Both sides use this: the simulated drives (``firmware_sim``) and the agent's CiA 402 drive
profile (``ersac_hil.agent``), which talks to the drives through python canopen's
``BaseNode402``. Units on the bus are the profile's: positions in encoder increments of the
motor encoder, velocities in increments per second, torque and current in per mille of the
motor's rated torque / current, the DC-link voltage in mV; ``DriveScaling`` converts to SI
joint units from a drive's gear ratio, encoder resolution and rated values.

PDO layout (one drive per axis, four frames of which three are cyclic)::

    RPDO1 (event-driven, applied on arrival)  controlword 0x6040, modes of operation 0x6060
    RPDO2 (synchronous, applied at SYNC)      target position 0x607A, target torque 0x6071
    TPDO1 (event-driven, on change + timer)   statusword 0x6041, modes of operation display 0x6061
    TPDO2 (synchronous)                       statusword 0x6041, position actual 0x6064
    TPDO3 (synchronous)                       velocity actual 0x606C, torque actual 0x6077,
                                              current actual 0x6078

The controlword and the mode travel event-driven, so the power state machine and a mode
switch work without a SYNC stream (``BaseNode402`` sends a non-periodic RPDO at once and
reads the statusword from the event-driven TPDO), and a quick stop takes effect on arrival
rather than at the next SYNC.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from protocol.can.objects import DataType, ObjectSpec

DEVICE_TYPE = 0x00020192
"""0x1000 of a CiA 402 servo drive: profile 402 (0x0192), type 0x0002 (servo drive)."""

EVENT_TIMER_MS = 100
"""Event timer of the event-driven TPDO1: the statusword at least this often while operational
(``BaseNode402`` waits up to 0.2 s for a TPDO it has seen twice)."""


class Index(enum.IntEnum):
    """Profile (0x6000-) and manufacturer (0x2012) objects of the drive."""
    ERROR_CODE = 0x603F
    CONTROLWORD = 0x6040
    STATUSWORD = 0x6041
    QUICK_STOP_OPTION = 0x605A
    MODES_OF_OPERATION = 0x6060
    MODES_DISPLAY = 0x6061
    POSITION_ACTUAL = 0x6064
    VELOCITY_ACTUAL = 0x606C
    TARGET_TORQUE = 0x6071
    MAX_TORQUE = 0x6072
    MAX_CURRENT = 0x6073
    RATED_CURRENT = 0x6075
    RATED_TORQUE = 0x6076
    TORQUE_ACTUAL = 0x6077
    CURRENT_ACTUAL = 0x6078
    DC_LINK_VOLTAGE = 0x6079
    TARGET_POSITION = 0x607A
    SOFTWARE_POSITION_LIMIT = 0x607D   # sub1 min, sub2 max (increments)
    MAX_MOTOR_SPEED = 0x6080
    ENCODER_RESOLUTION = 0x608F        # sub1 increments, sub2 motor revolutions
    GEAR_RATIO = 0x6091                # sub1 motor revolutions, sub2 shaft revolutions
    INTERPOLATION_PERIOD = 0x60C2      # sub1 value, sub2 index (power of ten of seconds)
    SUPPORTED_MODES = 0x6502
    IMPEDANCE = 0x2012                 # sub1 Kp, sub2 Kd (manufacturer, MAB MD style)


class Mode(enum.IntEnum):
    """Modes of operation (0x6060/0x6061) this project's drives know."""
    NO_MODE = 0
    CYCLIC_SYNCHRONOUS_POSITION = 8
    CYCLIC_SYNCHRONOUS_TORQUE = 10

    @property
    def supported_bit(self) -> int:
        """The mode's bit in 0x6502 (bit ``mode - 1``)."""
        return 0 if self is Mode.NO_MODE else 1 << (self.value - 1)


CSP, CST = Mode.CYCLIC_SYNCHRONOUS_POSITION, Mode.CYCLIC_SYNCHRONOUS_TORQUE
SUPPORTED_MODES = CSP.supported_bit | CST.supported_bit
"""0x6502 of the project's drives: CSP (bit 7) and CST (bit 9)."""


class State(enum.Enum):
    """The power drive system's states, with the statusword (mask, value) that shows each
    (CiA 402 table 30; the names are ``BaseNode402``'s)."""
    NOT_READY_TO_SWITCH_ON = ("NOT READY TO SWITCH ON", 0x4F, 0x00)
    SWITCH_ON_DISABLED = ("SWITCH ON DISABLED", 0x4F, 0x40)
    READY_TO_SWITCH_ON = ("READY TO SWITCH ON", 0x6F, 0x21)
    SWITCHED_ON = ("SWITCHED ON", 0x6F, 0x23)
    OPERATION_ENABLED = ("OPERATION ENABLED", 0x6F, 0x27)
    QUICK_STOP_ACTIVE = ("QUICK STOP ACTIVE", 0x6F, 0x07)
    FAULT_REACTION_ACTIVE = ("FAULT REACTION ACTIVE", 0x4F, 0x0F)
    FAULT = ("FAULT", 0x4F, 0x08)

    def __init__(self, label: str, mask: int, bits: int) -> None:
        self.label, self.mask, self.bits = label, mask, bits

    @classmethod
    def of(cls, statusword: int) -> "State | None":
        """The state a statusword shows (``None``: no valid state)."""
        for state in cls:
            if statusword & state.mask == state.bits:
                return state
        return None


class Statusword(enum.IntFlag):
    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5          # 0: quick stop active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    INTERNAL_LIMIT = 1 << 11
    DRIVE_FOLLOWS = 1 << 12      # CSP/CST: the drive follows the command value


class Controlword(enum.IntFlag):
    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2          # 0: quick stop
    ENABLE_OPERATION = 1 << 3
    FAULT_RESET = 1 << 7         # rising edge
    HALT = 1 << 8


class Command(enum.Enum):
    """Device control commands (CiA 402 table 28): (mask, value) of the controlword bits 0-3, 7.
    ``SWITCH_ON`` is also "disable operation" (the same code, from OPERATION ENABLED)."""
    SHUTDOWN = (0x87, 0x06)
    SWITCH_ON = (0x8F, 0x07)
    DISABLE_VOLTAGE = (0x82, 0x00)
    QUICK_STOP = (0x86, 0x02)
    ENABLE_OPERATION = (0x8F, 0x0F)

    def __init__(self, mask: int, bits: int) -> None:
        self.mask, self.bits = mask, bits

    @classmethod
    def of(cls, controlword: int) -> "Command | None":
        """The command a controlword gives (``None``: none, e.g. bit 7 set for a fault reset)."""
        for command in (cls.DISABLE_VOLTAGE, cls.QUICK_STOP, cls.SHUTDOWN, cls.ENABLE_OPERATION,
                        cls.SWITCH_ON):
            if controlword & command.mask == command.bits:
                return command
        return None


class QuickStopOption(enum.IntEnum):
    """0x605A values the project's drives accept."""
    DISABLE_DRIVE = 0        # torque off at once, to SWITCH ON DISABLED
    SLOW_DOWN_RAMP = 1       # decelerate, then SWITCH ON DISABLED
    QUICK_STOP_RAMP = 2      # the same on the quick-stop ramp (the drive's braking law)
    SLOW_DOWN_STAY = 5       # decelerate, stay in QUICK STOP ACTIVE (holding)
    QUICK_STOP_STAY = 6      # the same on the quick-stop ramp


QUICK_STOP_DEFAULT = QuickStopOption.QUICK_STOP_STAY


# ---- the objects ---------------------------------------------------------------------------
_T = DataType


def _o(index: int, name: str, dtype: DataType, access: str = "rw", pdo: bool = False,
       low: int | None = None, high: int | None = None, meaning: str = "") -> ObjectSpec:
    return ObjectSpec(index, name, dtype, access, pdo, low, high, meaning=meaning)


OBJECTS: dict[int, ObjectSpec] = {o.index: o for o in (
    _o(Index.ERROR_CODE, "Error code", _T.UINT16, "ro", False,
       meaning="the EMCY code of the present fault (protocol.can.objects.EmcyCode), 0 none"),
    _o(Index.CONTROLWORD, "Controlword", _T.UINT16, "rw", True, meaning="CiA 402 device control"),
    _o(Index.STATUSWORD, "Statusword", _T.UINT16, "ro", True, meaning="CiA 402 power state"),
    _o(Index.QUICK_STOP_OPTION, "Quick stop option code", _T.INT16, "rw", False, 0, 6,
       meaning="0 torque off, 1/2 brake then disable, 5/6 brake and hold"),
    _o(Index.MODES_OF_OPERATION, "Modes of operation", _T.INT8, "rw", True, -128, 127,
       meaning="8 cyclic synchronous position, 10 cyclic synchronous torque"),
    _o(Index.MODES_DISPLAY, "Modes of operation display", _T.INT8, "ro", True),
    _o(Index.POSITION_ACTUAL, "Position actual value", _T.INT32, "ro", True,
       meaning="motor encoder increments"),
    _o(Index.VELOCITY_ACTUAL, "Velocity actual value", _T.INT32, "ro", True,
       meaning="motor encoder increments per second"),
    _o(Index.TARGET_TORQUE, "Target torque", _T.INT16, "rw", True,
       meaning="per mille of the rated torque"),
    _o(Index.MAX_TORQUE, "Max torque", _T.UINT16, "rw", False, 0, 1000,
       meaning="per mille of the rated torque"),
    _o(Index.MAX_CURRENT, "Max current", _T.UINT16, "rw", False, 0, 1000,
       meaning="per mille of the rated current"),
    _o(Index.RATED_CURRENT, "Motor rated current", _T.UINT32, "ro", False, meaning="mA"),
    _o(Index.RATED_TORQUE, "Motor rated torque", _T.UINT32, "ro", False, meaning="mN m (motor side)"),
    _o(Index.TORQUE_ACTUAL, "Torque actual value", _T.INT16, "ro", True,
       meaning="per mille of the rated torque"),
    _o(Index.CURRENT_ACTUAL, "Current actual value", _T.INT16, "ro", True,
       meaning="per mille of the rated current"),
    _o(Index.DC_LINK_VOLTAGE, "DC link circuit voltage", _T.UINT32, "ro", True, meaning="mV"),
    _o(Index.TARGET_POSITION, "Target position", _T.INT32, "rw", True,
       meaning="motor encoder increments"),
    _o(Index.SOFTWARE_POSITION_LIMIT, "Software position limit", _T.INT32, "rw", False,
       meaning="motor encoder increments"),
    _o(Index.MAX_MOTOR_SPEED, "Max motor speed", _T.UINT32, "rw", False, meaning="rpm (motor)"),
    _o(Index.ENCODER_RESOLUTION, "Position encoder resolution", _T.UINT32, "ro", False,
       meaning="increments per motor revolutions"),
    _o(Index.GEAR_RATIO, "Gear ratio", _T.UINT32, "ro", False,
       meaning="motor revolutions per shaft revolutions"),
    _o(Index.INTERPOLATION_PERIOD, "Interpolation time period", _T.UINT8, "rw", False,
       meaning="sub1 value, sub2 index: value 10^index s, the SYNC period"),
    _o(Index.SUPPORTED_MODES, "Supported drive modes", _T.UINT32, "ro", False,
       meaning="bit 7 cyclic synchronous position, bit 9 cyclic synchronous torque"),
    _o(Index.IMPEDANCE, "Impedance gains", _T.UINT32, "rw", False, 0, 5_000_000,
       meaning="CSP law: sub1 Kp in 1e-3 N m/rad, sub2 Kd in 1e-4 N m s/rad (joint side)"),
)}
"""The drive's profile objects: name, type, access, PDO mappability, raw limits, meaning.
``tools/gen_eds.py`` writes ``cia402_drive.eds`` from it."""

KP_FACTOR = 1e-3
"""N m/rad per count of 0x2012:1 (joint side)."""
KD_FACTOR = 1e-4
"""N m s/rad per count of 0x2012:2 (joint side)."""

ENCODER_INCREMENTS = 16384
"""0x608F:1 default (per motor revolution, a 14-bit encoder)."""


@dataclass(frozen=True)
class DriveScaling:
    """SI joint units <-> the profile's units of one drive.

    Attributes:
        gear: motor revolutions per joint revolution (0x6091:1 / 0x6091:2).
        increments: encoder increments per motor revolution (0x608F:1 / 0x608F:2).
        rated_current: A (0x6075 / 1000). rated_torque: motor-side N m (0x6076 / 1000).
    """
    gear: float
    increments: float
    rated_current: float
    rated_torque: float

    @property
    def rad_per_increment(self) -> float:
        """Joint radians per encoder increment."""
        return 2.0 * math.pi / (self.gear * self.increments)

    @property
    def joint_torque_per_mille(self) -> float:
        """Joint-side N m per per-mille of the rated torque."""
        return self.rated_torque * self.gear / 1000.0

    @property
    def amps_per_mille(self) -> float:
        return self.rated_current / 1000.0

    def position(self, increments: int) -> float:
        return increments * self.rad_per_increment

    def increments_of(self, rad: float) -> int:
        return _clamp_i32(round(rad / self.rad_per_increment))

    def velocity(self, increments_per_s: int) -> float:
        return increments_per_s * self.rad_per_increment

    def torque(self, per_mille: int) -> float:
        """Joint-side N m."""
        return per_mille * self.joint_torque_per_mille

    def per_mille_of_torque(self, joint_torque: float) -> int:
        return _clamp_i16(round(joint_torque / self.joint_torque_per_mille))

    def current(self, per_mille: int) -> float:
        return per_mille * self.amps_per_mille


def _clamp_i32(v: int) -> int:
    return max(-(1 << 31), min((1 << 31) - 1, v))


def _clamp_i16(v: int) -> int:
    return max(-(1 << 15), min((1 << 15) - 1, v))
