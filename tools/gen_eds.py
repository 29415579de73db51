"""Generate the bench's EDS files (protocol/can/eds/*.eds) from one compact description.

The EDS files are the contract (both the agent and the simulator load them); this script is
how they are kept consistent. Run `python tools/gen_eds.py` after editing, commit both.
`tests/protocol/test_eds.py` fails when the committed files differ from what this writes.

Scaling of every manufacturer object is documented in docs/protocol.md (generated from the
EDS by `python tools/gen_protocol_doc.py`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "protocol" / "can" / "eds"

# CiA 301 data type codes
BOOLEAN, INT8, INT16, INT32, UINT8, UINT16, UINT32, REAL32, VSTRING = (
    0x0001, 0x0002, 0x0003, 0x0004, 0x0005, 0x0006, 0x0007, 0x0008, 0x0009)
BITS = {INT8: 8, INT16: 16, INT32: 32, UINT8: 8, UINT16: 16, UINT32: 32, BOOLEAN: 1}

VENDOR_ID = 0x00E2_5AC0  # ersac-hil project vendor id (not a registered CiA id)


@dataclass(frozen=True)
class Var:
    """One variable (or one element type of an ARRAY)."""
    name: str
    dtype: int
    access: str = "rw"
    default: str = "0"
    low: int | None = None
    high: int | None = None
    pdo: bool = False
    unit: str = ""  # "unit per count" note for the doc, e.g. "1e-4 rad"


@dataclass(frozen=True)
class Obj:
    index: int
    var: Var
    count: int = 0          # 0: VAR; >0: ARRAY with sub1..count
    sub_names: tuple[str, ...] = ()


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


# ---- manufacturer objects -------------------------------------------------------------------
def axis_objects(axes: tuple[str, ...], pos_type: int, current_limit: str) -> list[Obj]:
    n = len(axes)
    return [
        Obj(0x2000, Var("Position actual", pos_type, "ro", pdo=True, unit="1e-4 rad"), n, axes),
        Obj(0x2001, Var("Velocity actual", INT16, "ro", pdo=True, unit="1e-3 rad/s"), n, axes),
        Obj(0x2002, Var("Motor current", INT16, "ro", pdo=True, unit="1 mA"), n, axes),
        Obj(0x2003, Var("Motor voltage", INT16, "ro", pdo=True, unit="1 mV"), n, axes),
        Obj(0x2034, Var("Current limit", UINT16, default=current_limit, low=0, high=30000, unit="1 mA"), n, axes),
    ]


STATUS = Obj(0x2010, Var("Status word", UINT16, "ro", pdo=True, unit="bits"))
CONTROL = Obj(0x2011, Var("Control word", UINT16, "rw", pdo=True, unit="bits"))


def joint_objects(axes: tuple[str, ...], stiffness: str, damping: str) -> list[Obj]:
    n = len(axes)
    return [
        Obj(0x2021, Var("Position setpoint", INT16, pdo=True, low=-31416, high=31416, unit="1e-4 rad"), n, axes),
        Obj(0x2030, Var("Joint stiffness", UINT16, default=stiffness, low=0, high=50000, unit="0.01 Nm/rad"), n, axes),
        Obj(0x2031, Var("Joint damping", UINT16, default=damping, low=0, high=50000, unit="1e-3 Nm s/rad"), n, axes),
        Obj(0x2032, Var("Position limit min", INT16, default="-31416", low=-31416, high=31416, unit="1e-4 rad"), n, axes),
        Obj(0x2033, Var("Position limit max", INT16, default="31416", low=-31416, high=31416, unit="1e-4 rad"), n, axes),
        Obj(0x2035, Var("Velocity limit", UINT16, default="10000", low=0, high=30000, unit="1e-3 rad/s"), n, axes),
    ]


KNOTS = tuple(f"Knot {i}" for i in range(1, 9))


def spline_objects(axes: tuple[str, ...]) -> list[Obj]:
    objs = [
        Obj(0x2040, Var("Spline knot count", UINT8, default="0", low=0, high=8, unit="knots")),
        Obj(0x2041, Var("Spline knot time", UINT16, low=0, high=60000, unit="1 ms"), 8, KNOTS),
    ]
    for i, axis in enumerate(axes):
        objs.append(Obj(0x2042 + 2 * i, Var(f"Spline position {axis}", INT16, low=-31416, high=31416,
                                            unit="1e-4 rad"), 8, KNOTS))
        objs.append(Obj(0x2043 + 2 * i, Var(f"Spline velocity {axis}", INT16, low=-30000, high=30000,
                                            unit="1e-3 rad/s"), 8, KNOTS))
    return objs


def pdo(*entries: tuple[int, int, int]) -> tuple[tuple[int, int, int], ...]:
    return entries


def devices() -> list[Device]:
    wheels = ("left", "right")
    wheel = Device("wheel.eds", "uBot wheel controller", 0x0001,
                   "Two-axis DC motor controller for the differential-drive wheels (torque mode)",
                   wheels)
    wheel.objects = axis_objects(wheels, INT32, "10000") + [
        STATUS, CONTROL,
        Obj(0x2020, Var("Torque command", INT16, pdo=True, low=-20000, high=20000, unit="1 mNm"), 2, wheels),
    ]
    wheel.tpdos = [pdo((0x2000, 1, 32), (0x2000, 2, 32)),
                   pdo((0x2001, 1, 16), (0x2001, 2, 16), (0x2002, 1, 16), (0x2002, 2, 16)),
                   pdo((0x2003, 1, 16), (0x2003, 2, 16), (0x2010, 0, 16))]
    wheel.rpdos = [pdo((0x2020, 1, 16), (0x2020, 2, 16), (0x2011, 0, 16))]

    torso_axes = ("torso",)
    torso = Device("torso.eds", "uBot torso controller", 0x0002,
                   "One-axis DC motor controller for torso rotation (joint impedance mode)", torso_axes)
    torso.objects = axis_objects(torso_axes, INT16, "4000") + [STATUS, CONTROL] + joint_objects(torso_axes, "20000", "2000")
    torso.tpdos = [pdo((0x2000, 1, 16), (0x2001, 1, 16), (0x2002, 1, 16), (0x2003, 1, 16)),
                   pdo((0x2010, 0, 16))]
    torso.rpdos = [pdo((0x2021, 1, 16), (0x2011, 0, 16))]

    arm_axes = ("shoulder", "elbow")
    arm = Device("arm.eds", "uBot arm controller", 0x0003,
                 "Two-axis DC motor controller for one arm (shoulder, elbow): joint impedance, "
                 "on-board cubic spline tracking", arm_axes)
    arm.objects = (axis_objects(arm_axes, INT16, "12000") + [STATUS, CONTROL]
                   + joint_objects(arm_axes, "5000", "500") + spline_objects(arm_axes))
    arm.tpdos = [pdo((0x2000, 1, 16), (0x2000, 2, 16), (0x2001, 1, 16), (0x2001, 2, 16)),
                 pdo((0x2002, 1, 16), (0x2002, 2, 16), (0x2003, 1, 16), (0x2003, 2, 16)),
                 pdo((0x2010, 0, 16))]
    arm.rpdos = [pdo((0x2021, 1, 16), (0x2021, 2, 16), (0x2011, 0, 16))]

    imu = Device("imu.eds", "uBot IMU", 0x0004, "Body inertial measurement unit (pitch axis)")
    imu.objects = [
        STATUS,
        Obj(0x2100, Var("Pitch", INT16, "ro", pdo=True, unit="1e-4 rad")),
        Obj(0x2101, Var("Pitch rate", INT16, "ro", pdo=True, unit="1e-3 rad/s")),
        Obj(0x2102, Var("Pitch acceleration", INT16, "ro", pdo=True, unit="0.1 rad/s^2")),
        Obj(0x2103, Var("Acceleration x", INT16, "ro", pdo=True, unit="0.01 m/s^2")),
        Obj(0x2104, Var("Acceleration z", INT16, "ro", pdo=True, unit="0.01 m/s^2")),
    ]
    imu.tpdos = [pdo((0x2100, 0, 16), (0x2101, 0, 16), (0x2102, 0, 16), (0x2010, 0, 16)),
                 pdo((0x2103, 0, 16), (0x2104, 0, 16))]

    bench = Device("testbench.eds", "uBot simulated test bench", 0x00F0,
                   "Simulator-only node: scenario selection, seed, reset, impact trigger, ground truth")
    bench.objects = [
        STATUS,
        Obj(0x3000, Var("Scenario", UINT8, default="0", low=0, high=2, unit="0 idle, 1 bracing, 2 lifting")),
        Obj(0x3001, Var("Seed", UINT32, default="0", unit="-")),
        Obj(0x3002, Var("Reset", UINT8, default="0", low=0, high=1, unit="write 1: reset scenario")),
        Obj(0x3003, Var("Impact trigger", UINT8, default="0", low=0, high=1, unit="write 1: release pendulum")),
        Obj(0x3004, Var("Impact momentum", UINT16, "ro", unit="0.01 Ns")),
        Obj(0x3005, Var("Cable tension", UINT16, "ro", unit="0.1 N"), 2, ("left", "right")),
        Obj(0x3006, Var("Bottle height", INT16, "ro", unit="1 mm")),
        Obj(0x3007, Var("Simulated time", UINT32, "ro", unit="1 us")),
        Obj(0x3008, Var("Ground truth flags", UINT16, "ro", unit="status bits")),
        Obj(0x3009, Var("Balance free", UINT8, default="0", low=0, high=1, unit="1: wheels passive")),
        Obj(0x300A, Var("Bottle COM height", INT16, "ro", unit="1 mm")),
    ]
    return [wheel, torso, arm, imu, bench]


# ---- EDS writer -----------------------------------------------------------------------------
def _var_lines(name: str, v: Var, default: str | None = None) -> list[str]:
    lines = [f"ParameterName={name}", "ObjectType=0x7", f"DataType=0x{v.dtype:04X}",
             f"AccessType={v.access}", f"DefaultValue={v.default if default is None else default}",
             f"PDOMapping={1 if v.pdo else 0}"]
    if v.low is not None:
        lines.append(f"LowLimit={v.low}")
    if v.high is not None:
        lines.append(f"HighLimit={v.high}")
    return lines


def _section(out: list[str], head: str, lines: list[str]) -> None:
    out.append(f"[{head}]")
    out.extend(lines)
    out.append("")


def _u32(name: str, default: str, access: str = "rw") -> Var:
    return Var(name, UINT32, access, default)


def _record(out: list[str], index: int, name: str, subs: list[tuple[str, Var]], objtype: int = 0x9) -> None:
    _section(out, f"{index:04X}", [f"ParameterName={name}", f"ObjectType=0x{objtype:X}",
                                   f"SubNumber={len(subs) + 1}"])
    _section(out, f"{index:04X}sub0", _var_lines("Highest sub-index supported",
                                                 Var("", UINT8, "ro", str(len(subs)))))
    for i, (sname, var) in enumerate(subs, start=1):
        _section(out, f"{index:04X}sub{i:X}", _var_lines(sname, var))


def render(dev: Device) -> str:
    mandatory = [0x1000, 0x1001, 0x1018]
    optional: list[int] = []
    body: list[str] = []

    def var(index: int, v: Var) -> None:
        _section(body, f"{index:04X}", _var_lines(v.name, v))

    var(0x1000, Var("Device type", UINT32, "ro", "0x00000000"))
    var(0x1001, Var("Error register", UINT8, "ro", "0"))
    optional += [0x1005, 0x1008, 0x1014, 0x1016, 0x1017]
    var(0x1005, Var("COB-ID SYNC", UINT32, "rw", "0x00000080"))
    var(0x1008, Var("Manufacturer device name", VSTRING, "const", dev.name))
    var(0x1014, Var("COB-ID EMCY", UINT32, "rw", "$NODEID+0x80"))
    # Consumer heartbeat: sub1 = agent node 0x01, 250 ms (the agent produces every 100 ms).
    _record(body, 0x1016, "Consumer heartbeat time",
            [("Consumer heartbeat time 1", _u32("", "0x000100FA"))], objtype=0x8)
    var(0x1017, Var("Producer heartbeat time", UINT16, "rw", "100", unit="1 ms"))
    _record(body, 0x1018, "Identity object", [
        ("Vendor-ID", _u32("", f"0x{VENDOR_ID:08X}", "ro")),
        ("Product code", _u32("", f"0x{dev.product:08X}", "ro")),
        ("Revision number", _u32("", "0x00010000", "ro")),
        ("Serial number", _u32("", "$NODEID+0x5E000000", "ro")),
    ])
    for n, entries in enumerate(dev.rpdos):
        optional += [0x1400 + n, 0x1600 + n]
        _record(body, 0x1400 + n, f"RPDO {n + 1} communication parameter", [
            ("COB-ID used by RPDO", _u32("", f"$NODEID+0x{0x200 + 0x100 * n:X}")),
            ("Transmission type", Var("", UINT8, "rw", "1")),
        ])
        _record(body, 0x1600 + n, f"RPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32("", f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    for n, entries in enumerate(dev.tpdos):
        optional += [0x1800 + n, 0x1A00 + n]
        _record(body, 0x1800 + n, f"TPDO {n + 1} communication parameter", [
            ("COB-ID used by TPDO", _u32("", f"$NODEID+0x{0x180 + 0x100 * n:X}")),
            ("Transmission type", Var("", UINT8, "rw", "1")),
            ("Inhibit time", Var("", UINT16, "rw", "0")),
            ("Reserved", Var("", UINT8, "rw", "0")),
            ("Event timer", Var("", UINT16, "rw", "0")),
        ])
        _record(body, 0x1A00 + n, f"TPDO {n + 1} mapping parameter", [
            (f"Mapped object {i + 1}", _u32("", f"0x{ix:04X}{sub:02X}{bits:02X}"))
            for i, (ix, sub, bits) in enumerate(entries)])
    manufacturer: list[int] = []
    for obj in sorted(dev.objects, key=lambda o: o.index):
        manufacturer.append(obj.index)
        if obj.count == 0:
            var(obj.index, obj.var)
        else:
            _record(body, obj.index, obj.var.name,
                    [(f"{obj.var.name} {s}", obj.var) for s in obj.sub_names], objtype=0x8)
    # unit notes, one per manufacturer object, for the generated documentation
    units = [f"0x{o.index:04X}={o.var.unit}" for o in sorted(dev.objects, key=lambda o: o.index)]

    head: list[str] = []
    _section(head, "FileInfo", [f"FileName={dev.file}", "FileVersion=1", "FileRevision=0",
                                "EDSVersion=4.0", f"Description={dev.description}",
                                "CreatedBy=ersac-hil tools/gen_eds.py"])
    _section(head, "DeviceInfo", ["VendorName=ersac-hil", f"VendorNumber=0x{VENDOR_ID:08X}",
                                  f"ProductName={dev.name}", f"ProductNumber=0x{dev.product:08X}",
                                  "BaudRate_1000=1", "SimpleBootUpMaster=0", "SimpleBootUpSlave=1",
                                  "Granularity=8", f"NrOfRXPDO={len(dev.rpdos)}",
                                  f"NrOfTXPDO={len(dev.tpdos)}", "LSS_Supported=0"])
    _section(head, "Comments", [f"Lines={len(units) + (1 if dev.axes else 0)}"]
             + ([f"Line1=Axes: {', '.join(dev.axes)}"] if dev.axes else [])
             + [f"Line{i + 1 + (1 if dev.axes else 0)}=Unit {u}" for i, u in enumerate(units)])
    for title, idxs in (("MandatoryObjects", mandatory), ("OptionalObjects", optional),
                        ("ManufacturerObjects", manufacturer)):
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
