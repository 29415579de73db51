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
from dataclasses import dataclass, field
from pathlib import Path

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
    """A manufacturer object of one device: VAR (``sub_names`` empty) or ARRAY over them."""
    spec: ObjectSpec
    default: str = "0"
    sub_names: tuple[str, ...] = ()

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
    return [wheel, torso, arm, imu, testbench]


# ---- EDS writer -----------------------------------------------------------------------------
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

    var(0x1000, Var("Device type", DataType.UINT32, "ro", "0x00000000"))
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
            ("COB-ID used by RPDO", _u32(f"$NODEID+0x{0x200 + 0x100 * n:X}")),
            ("Transmission type", Var("", DataType.UINT8, "rw", "1")),
        ])
        _record(body, 0x1600 + n, f"RPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32(f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    for n, entries in enumerate(dev.tpdos):
        optional += [0x1800 + n, 0x1A00 + n]
        _record(body, 0x1800 + n, f"TPDO {n + 1} communication parameter", [
            ("COB-ID used by TPDO", _u32(f"$NODEID+0x{0x180 + 0x100 * n:X}")),
            ("Transmission type", Var("", DataType.UINT8, "rw", "1")),
            ("Inhibit time", Var("", DataType.UINT16, "rw", "0")),
            ("Reserved", Var("", DataType.UINT8, "rw", "0")),
            ("Event timer", Var("", DataType.UINT16, "rw", "0")),
        ])
        _record(body, 0x1A00 + n, f"TPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32(f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    manufacturer = sorted(dev.objects, key=lambda o: o.index)
    for o in manufacturer:
        _manufacturer(body, o)

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
    OUT.mkdir(parents=True, exist_ok=True)
    stale = []
    for dev in devices():
        text = render(dev)
        path = OUT / dev.file
        if check:
            if not path.exists() or path.read_text() != text:
                stale.append(dev.file)
        else:
            path.write_text(text)
    if stale:
        print("stale EDS files (run python tools/gen_eds.py):", ", ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(check="--check" in sys.argv))
