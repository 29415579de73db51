"""Generate the devices' EDS files (protocol/can/eds/*.eds) from the object table in
``protocol.can.objects`` (indices, names, types, access, limits, scaling) and the device
table in ``protocol.can.devices`` (axes, heartbeat periods). What is decided here: which objects
each device has, their per-device defaults, and the PDO maps.

The EDS files are the contract (both the agent and the simulator load them). Run
`python tools/gen_eds.py` after editing, commit both; `tests/protocol/test_eds.py` fails when
the committed files differ from what this writes. Scaling is written as the (non-standard,
canopen-supported) ``Factor``/``Unit`` keys; docs/protocol.md is generated from the EDS files
by `python tools/gen_protocol_doc.py`.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

from protocol.can import cia402
from protocol.can.devices import (AGENT_NODE_ID, ARM_LEFT, CONSUMER_HEARTBEAT_MS, HEARTBEAT_PERIOD_MS,
                                TORSO, WHEELS)
from protocol.can.objects import (OBJECTS, SPLINE_MAX_KNOTS, WHEEL_POSITION_OBJECT, DataType, Index,
                                  ObjectSpec, spline_position_index, spline_velocity_index)

OUT = Path(__file__).resolve().parents[1] / "protocol" / "can" / "eds"

VENDOR_ID = 0x00E2_5AC0  # ersac-hil project vendor id (not a registered CiA id)


@dataclass(frozen=True)
class Var:
    """One communication-area variable (or a record's sub-entry)."""
    name: str
    dtype: int
    access: str = "rw"
    default: str = "0"


@dataclass(frozen=True)
class Obj:
    """An application object of one device: VAR (``sub_names`` and ``subs`` empty), ARRAY over
    ``sub_names`` (one spec, one default), or RECORD of ``subs`` (name, spec, default each)."""
    spec: ObjectSpec
    default: str = "0"
    sub_names: tuple[str, ...] = ()
    subs: tuple[tuple[str, ObjectSpec, str], ...] = ()

    @property
    def index(self) -> int:
        return self.spec.index


@dataclass
class Device:
    file: str
    name: str
    product: int
    description: str
    axes: tuple[str, ...] = ()
    objects: list[Obj] = field(default_factory=list)
    rpdos: list[tuple[tuple[int, int, int], ...]] = field(default_factory=list)
    tpdos: list[tuple[tuple[int, int, int], ...]] = field(default_factory=list)
    device_type: int = 0
    events: dict[tuple[str, int], int] = field(default_factory=dict)
    """Event-driven PDOs (transmission type 255) by (``"rpdo"``/``"tpdo"``, number), with the
    TPDO's event timer in ms; the others are synchronous (type 1). An empty map: a disabled PDO."""


# ---- manufacturer objects of each device ------------------------------------------------------
def obj(index: int, default: str = "0", axes: tuple[str, ...] = ()) -> Obj:
    return Obj(OBJECTS[index], default, axes)


def axis_objects(axes: tuple[str, ...], current_limit: str, position: ObjectSpec = OBJECTS[Index.POSITION]
                 ) -> list[Obj]:
    return [Obj(position, "0", axes), obj(Index.VELOCITY, axes=axes), obj(Index.CURRENT, axes=axes),
            obj(Index.VOLTAGE, axes=axes), obj(Index.CURRENT_LIMIT, current_limit, axes)]


STATUS, CONTROL = obj(Index.STATUS), obj(Index.CONTROL)


def joint_objects(axes: tuple[str, ...], stiffness: str, damping: str) -> list[Obj]:
    return [obj(Index.POSITION_SETPOINT, axes=axes), obj(Index.STIFFNESS, stiffness, axes),
            obj(Index.DAMPING, damping, axes),
            obj(Index.POSITION_LIMIT_MIN, str(OBJECTS[Index.POSITION_LIMIT_MIN].low), axes),
            obj(Index.POSITION_LIMIT_MAX, str(OBJECTS[Index.POSITION_LIMIT_MAX].high), axes),
            obj(Index.VELOCITY_LIMIT, "10000", axes)]


KNOTS = tuple(f"Knot {i}" for i in range(1, SPLINE_MAX_KNOTS + 1))


def spline_objects(axes: tuple[str, ...]) -> list[Obj]:
    objs = [obj(Index.SPLINE_KNOT_COUNT), obj(Index.SPLINE_KNOT_TIME, axes=KNOTS)]
    for i, axis in enumerate(axes, start=1):
        position, velocity = OBJECTS[Index.SPLINE_POSITION], OBJECTS[Index.SPLINE_VELOCITY]
        objs.append(Obj(position.at(spline_position_index(i), f"{position.name} {axis}"), "0", KNOTS))
        objs.append(Obj(velocity.at(spline_velocity_index(i), f"{velocity.name} {axis}"), "0", KNOTS))
    return objs


def pdo(*entries: tuple[int, int, int]) -> tuple[tuple[int, int, int], ...]:
    return entries


def devices() -> list[Device]:
    wheel = Device("wheel.eds", "uBot wheel controller", 0x0001,
                   "Two-axis DC motor controller for the differential-drive wheels (torque mode)",
                   WHEELS.axes)
    wheel.objects = axis_objects(wheel.axes, "10000", WHEEL_POSITION_OBJECT) + [
        STATUS, CONTROL, obj(Index.TORQUE_COMMAND, axes=wheel.axes)]
    wheel.tpdos = [pdo((0x2000, 1, 32), (0x2000, 2, 32)),
                   pdo((0x2001, 1, 16), (0x2001, 2, 16), (0x2002, 1, 16), (0x2002, 2, 16)),
                   pdo((0x2003, 1, 16), (0x2003, 2, 16), (0x2010, 0, 16))]
    wheel.rpdos = [pdo((0x2020, 1, 16), (0x2020, 2, 16), (0x2011, 0, 16))]

    torso = Device("torso.eds", "uBot torso controller", 0x0002,
                   "One-axis DC motor controller for torso rotation (joint impedance mode)", TORSO.axes)
    torso.objects = (axis_objects(torso.axes, "4000") + [STATUS, CONTROL]
                     + joint_objects(torso.axes, "20000", "2000"))
    torso.tpdos = [pdo((0x2000, 1, 16), (0x2001, 1, 16), (0x2002, 1, 16), (0x2003, 1, 16)),
                   pdo((0x2010, 0, 16))]
    torso.rpdos = [pdo((0x2021, 1, 16), (0x2011, 0, 16))]

    arm = Device("arm.eds", "uBot arm controller", 0x0003,
                 "Two-axis DC motor controller for one arm (shoulder, elbow): joint impedance, "
                 "on-board cubic spline tracking", ARM_LEFT.axes)
    arm.objects = (axis_objects(arm.axes, "12000") + [STATUS, CONTROL]
                   + joint_objects(arm.axes, "5000", "500") + spline_objects(arm.axes))
    arm.tpdos = [pdo((0x2000, 1, 16), (0x2000, 2, 16), (0x2001, 1, 16), (0x2001, 2, 16)),
                 pdo((0x2002, 1, 16), (0x2002, 2, 16), (0x2003, 1, 16), (0x2003, 2, 16)),
                 pdo((0x2010, 0, 16))]
    arm.rpdos = [pdo((0x2021, 1, 16), (0x2021, 2, 16), (0x2011, 0, 16))]

    imu = Device("imu.eds", "uBot IMU", 0x0004, "Body inertial measurement unit (pitch axis)")
    imu.objects = [STATUS] + [obj(i) for i in (Index.PITCH, Index.PITCH_RATE, Index.PITCH_ACCELERATION,
                                               Index.ACCELERATION_X, Index.ACCELERATION_Z)]
    imu.tpdos = [pdo((0x2100, 0, 16), (0x2101, 0, 16), (0x2102, 0, 16), (0x2010, 0, 16)),
                 pdo((0x2103, 0, 16), (0x2104, 0, 16))]

    testbench = Device("testbench.eds", "uBot simulated test bench", 0x00F0,
                   "Simulator-only node: scenario selection, seed, reset, impact trigger, ground truth")
    testbench.objects = [STATUS] + [obj(i) for i in (
        Index.SCENARIO, Index.SEED, Index.RESET, Index.IMPACT_TRIGGER, Index.IMPACT_MOMENTUM)] + [
        obj(Index.CABLE_TENSION, axes=("left", "right"))] + [obj(i) for i in (
            Index.BOTTLE_HEIGHT, Index.SIM_TIME, Index.GROUND_TRUTH_FLAGS, Index.BALANCE_FREE,
            Index.BOTTLE_COM_HEIGHT)]
    return [wheel, torso, arm, imu, testbench, cia402_drive()]


def cia402_drive() -> Device:
    """One-axis CiA 402 servo drive (the PDO layout in ``protocol.can.cia402``)."""
    c, ix = cia402.OBJECTS, cia402.Index

    def var(index: int, default: object = 0) -> Obj:
        return Obj(c[index], str(default))

    def record(index: int, *subs: tuple[str, object]) -> Obj:
        spec = c[index]
        return Obj(spec, subs=tuple((f"{spec.name} {name}", spec, str(default)) for name, default in subs))

    period = record(ix.INTERPOLATION_PERIOD, ("value", 5), ("index", -3))
    value, index = period.subs
    period = replace(period, subs=(value, (index[0], replace(index[1], dtype=DataType.INT8, low=-128,
                                                                   high=127), index[2])))
    impedance = record(ix.IMPEDANCE, ("Kp", 50000), ("Kd", 5000))  # scaled per sub: a range check means something
    kp, kd = impedance.subs
    impedance = replace(impedance, subs=(
        (kp[0], replace(kp[1], factor=cia402.KP_FACTOR, unit="N m/rad"), kp[2]),
        (kd[0], replace(kd[1], factor=cia402.KD_FACTOR, unit="N m s/rad"), kd[2])))
    drive = Device("cia402_drive.eds", "ersac-hil CiA 402 servo drive", 0x0402,
                   "One-axis CiA 402 servo drive: cyclic synchronous position with the drive's own "
                   "impedance (0x2012), cyclic synchronous torque", ("axis",),
                   device_type=cia402.DEVICE_TYPE,
                   events={("rpdo", 1): 0, ("tpdo", 1): cia402.EVENT_TIMER_MS})
    drive.objects = [
        var(ix.ERROR_CODE), var(ix.CONTROLWORD), var(ix.STATUSWORD),
        var(ix.QUICK_STOP_OPTION, int(cia402.QUICK_STOP_DEFAULT)), var(ix.MODES_OF_OPERATION),
        var(ix.MODES_DISPLAY), var(ix.POSITION_ACTUAL), var(ix.VELOCITY_ACTUAL), var(ix.TARGET_TORQUE),
        var(ix.MAX_TORQUE, 1000), var(ix.MAX_CURRENT, 1000), var(ix.RATED_CURRENT, 10000),
        var(ix.RATED_TORQUE, 300), var(ix.TORQUE_ACTUAL), var(ix.CURRENT_ACTUAL),
        var(ix.DC_LINK_VOLTAGE, 24000), var(ix.TARGET_POSITION),
        record(ix.SOFTWARE_POSITION_LIMIT, ("min", -(1 << 31)), ("max", (1 << 31) - 1)),
        var(ix.MAX_MOTOR_SPEED, 10000),
        record(ix.ENCODER_RESOLUTION, ("increments", cia402.ENCODER_INCREMENTS), ("motor revolutions", 1)),
        record(ix.GEAR_RATIO, ("motor revolutions", 1), ("shaft revolutions", 1)),
        period, var(ix.SUPPORTED_MODES, f"0x{cia402.SUPPORTED_MODES:08X}"),
        impedance,
    ]
    cw, mode = (ix.CONTROLWORD, 0, 16), (ix.MODES_OF_OPERATION, 0, 8)
    sw = (ix.STATUSWORD, 0, 16)
    drive.rpdos = [pdo(cw, mode), pdo((ix.TARGET_POSITION, 0, 32), (ix.TARGET_TORQUE, 0, 16)), pdo(), pdo()]
    drive.tpdos = [pdo(sw, (ix.MODES_DISPLAY, 0, 8)), pdo(sw, (ix.POSITION_ACTUAL, 0, 32)),
                   pdo((ix.VELOCITY_ACTUAL, 0, 32), (ix.TORQUE_ACTUAL, 0, 16), (ix.CURRENT_ACTUAL, 0, 16)),
                   pdo()]
    return drive


# ---- EDS writer -----------------------------------------------------------------------------
def _cob_id(base: int, entries: tuple) -> str:
    """The pre-defined COB-ID; a PDO without entries is disabled (bit 31, "not valid")."""
    return f"$NODEID+0x{base:X}" if entries else f"$NODEID+0x{0x8000_0000 | base:X}"


def _trans_type(dev: Device, kind: str, n: int, entries: tuple) -> str:
    """1 (synchronous, every SYNC), or 255 for an event-driven or disabled PDO."""
    return "255" if (kind, n + 1) in dev.events or not entries else "1"


def _var_lines(name: str, v: Var) -> list[str]:
    return [f"ParameterName={name}", "ObjectType=0x7", f"DataType=0x{v.dtype:04X}",
            f"AccessType={v.access}", f"DefaultValue={v.default}", "PDOMapping=0"]


def _spec_lines(name: str, spec: ObjectSpec, default: str) -> list[str]:
    lines = [f"ParameterName={name}", "ObjectType=0x7", f"DataType=0x{spec.dtype:04X}",
             f"AccessType={spec.access}", f"DefaultValue={default}", f"PDOMapping={int(spec.pdo)}"]
    if spec.low is not None:
        lines.append(f"LowLimit={spec.low}")
    if spec.high is not None:
        lines.append(f"HighLimit={spec.high}")
    if spec.factor is not None:
        lines += [f"Factor={spec.factor!r}", f"Unit={spec.unit}"]
    if spec.meaning:
        lines.append(f"Description={spec.meaning}")
    return lines


def _section(out: list[str], head: str, lines: list[str]) -> None:
    out.append(f"[{head}]")
    out.extend(lines)
    out.append("")


def _u32(default: str, access: str = "rw") -> Var:
    return Var("", DataType.UINT32, access, default)


def _record_head(out: list[str], index: int, name: str, n: int, objtype: int) -> None:
    _section(out, f"{index:04X}", [f"ParameterName={name}", f"ObjectType=0x{objtype:X}",
                                   f"SubNumber={n + 1}"])
    _section(out, f"{index:04X}sub0", _var_lines("Highest sub-index supported",
                                                 Var("", DataType.UINT8, "ro", str(n))))


def _record(out: list[str], index: int, name: str, subs: list[tuple[str, Var]], objtype: int = 0x9) -> None:
    _record_head(out, index, name, len(subs), objtype)
    for i, (sname, var) in enumerate(subs, start=1):
        _section(out, f"{index:04X}sub{i:X}", _var_lines(sname, var))


def _manufacturer(out: list[str], o: Obj) -> None:
    if o.subs:
        _record_head(out, o.index, o.spec.name, len(o.subs), 0x9)
        for i, (name, spec, default) in enumerate(o.subs, start=1):
            _section(out, f"{o.index:04X}sub{i:X}", _spec_lines(name, spec, default))
        return
    if not o.sub_names:
        _section(out, f"{o.index:04X}", _spec_lines(o.spec.name, o.spec, o.default))
        return
    _record_head(out, o.index, o.spec.name, len(o.sub_names), 0x8)
    for i, sub in enumerate(o.sub_names, start=1):
        _section(out, f"{o.index:04X}sub{i:X}", _spec_lines(f"{o.spec.name} {sub}", o.spec, o.default))


def render(dev: Device) -> str:
    mandatory = [0x1000, 0x1001, 0x1018]
    optional: list[int] = []
    body: list[str] = []

    def var(index: int, v: Var) -> None:
        _section(body, f"{index:04X}", _var_lines(v.name, v))

    var(0x1000, Var("Device type", DataType.UINT32, "ro", f"0x{dev.device_type:08X}"))
    var(0x1001, Var("Error register", DataType.UINT8, "ro", "0"))
    optional += [0x1005, 0x1008, 0x1014, 0x1016, 0x1017]
    var(0x1005, Var("COB-ID SYNC", DataType.UINT32, "rw", "0x00000080"))
    var(0x1008, Var("Manufacturer device name", DataType.VISIBLE_STRING, "const", dev.name))
    var(0x1014, Var("COB-ID EMCY", DataType.UINT32, "rw", "$NODEID+0x80"))
    # Consumer heartbeat: sub1 = the agent's node-id and how long its silence is tolerated.
    _record(body, 0x1016, "Consumer heartbeat time",
            [("Consumer heartbeat time 1", _u32(f"0x{AGENT_NODE_ID << 16 | CONSUMER_HEARTBEAT_MS:08X}"))],
            objtype=0x8)
    var(0x1017, Var("Producer heartbeat time", DataType.UINT16, "rw", str(HEARTBEAT_PERIOD_MS)))
    _record(body, 0x1018, "Identity object", [
        ("Vendor-ID", _u32(f"0x{VENDOR_ID:08X}", "ro")),
        ("Product code", _u32(f"0x{dev.product:08X}", "ro")),
        ("Revision number", _u32("0x00010000", "ro")),
        ("Serial number", _u32("$NODEID+0x5E000000", "ro")),
    ])
    for n, entries in enumerate(dev.rpdos):
        optional += [0x1400 + n, 0x1600 + n]
        _record(body, 0x1400 + n, f"RPDO {n + 1} communication parameter", [
            ("COB-ID used by RPDO", _u32(_cob_id(0x200 + 0x100 * n, entries))),
            ("Transmission type", Var("", DataType.UINT8, "rw", _trans_type(dev, "rpdo", n, entries))),
        ])
        _record(body, 0x1600 + n, f"RPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32(f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    for n, entries in enumerate(dev.tpdos):
        optional += [0x1800 + n, 0x1A00 + n]
        _record(body, 0x1800 + n, f"TPDO {n + 1} communication parameter", [
            ("COB-ID used by TPDO", _u32(_cob_id(0x180 + 0x100 * n, entries))),
            ("Transmission type", Var("", DataType.UINT8, "rw", _trans_type(dev, "tpdo", n, entries))),
            ("Inhibit time", Var("", DataType.UINT16, "rw", "0")),
            ("Reserved", Var("", DataType.UINT8, "rw", "0")),
            ("Event timer", Var("", DataType.UINT16, "rw", str(dev.events.get(("tpdo", n + 1), 0)))),
        ])
        _record(body, 0x1A00 + n, f"TPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32(f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    application = sorted(dev.objects, key=lambda o: o.index)
    for o in application:
        _manufacturer(body, o)
    optional += [o.index for o in application if o.index >= 0x6000]
    manufacturer = [o for o in application if o.index < 0x6000]

    head: list[str] = []
    _section(head, "FileInfo", [f"FileName={dev.file}", "FileVersion=1", "FileRevision=0",
                                "EDSVersion=4.0", f"Description={dev.description}",
                                "CreatedBy=ersac-hil tools/gen_eds.py"])
    _section(head, "DeviceInfo", ["VendorName=ersac-hil", f"VendorNumber=0x{VENDOR_ID:08X}",
                                  f"ProductName={dev.name}", f"ProductNumber=0x{dev.product:08X}",
                                  "BaudRate_1000=1", "SimpleBootUpMaster=0", "SimpleBootUpSlave=1",
                                  "Granularity=8", f"NrOfRXPDO={len(dev.rpdos)}",
                                  f"NrOfTXPDO={len(dev.tpdos)}", "LSS_Supported=0"])
    if dev.axes:
        _section(head, "Comments", ["Lines=1", f"Line1=Axes: {', '.join(dev.axes)}"])
    for title, idxs in (("MandatoryObjects", mandatory), ("OptionalObjects", optional),
                        ("ManufacturerObjects", [o.index for o in manufacturer])):
        _section(head, title, [f"SupportedObjects={len(idxs)}"]
                 + [f"{i + 1}=0x{ix:04X}" for i, ix in enumerate(idxs)])
    return "\n".join(head + body)


def main(check: bool = False) -> int:
    from generated import write_or_check  # tools/, beside this script
    return write_or_check({OUT / dev.file: render(dev) for dev in devices()}, check, "EDS files", "gen_eds.py")


if __name__ == "__main__":
    sys.exit(main(check="--check" in sys.argv))
