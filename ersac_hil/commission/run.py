"""One commissioning pass over a bus (the I/O shell around ``checks``): scan, compare, read every
axis once, move nothing.

    report = commission(load_description("ubot5"), BusConfig("socketcan", "can0"))
    print(report.text()); exit(report.exit_status)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import canopen

from ersac_hil.commission.checks import Defect, DriveLimits, Expected, Found, check_limits, check_nodes
from ersac_hil.commission.fingerprint import fingerprint
from ersac_hil.commission.scan import (Identity, NoAnswer, eds_pdos, listen_heartbeats, read_identity,
                                       read_pdos, read_value, sdo_client)
from protocol.can.busconfig import BusConfig, open_network
from protocol.can.cia402 import DriveScaling, Index as P402
from protocol.robot import Axis, RobotDescription
from protocol.robot.eds import object_dictionary_file
from protocol.robot.model import Device


@dataclass(frozen=True)
class Report:
    """Attributes:
        description: what was checked. bus: where. defects: one per problem.
        identities: every node that answered (node-id order). readings: one line per axis.
        fingerprint: of the description and the robot's identities (what the agent checks).
    """
    description: RobotDescription
    bus: str
    defects: tuple[Defect, ...]
    identities: tuple[Identity, ...]
    readings: tuple[str, ...] = ()
    fingerprint: str = ""
    notes: tuple[str, ...] = field(default=())

    @property
    def passed(self) -> bool:
        return not self.defects

    @property
    def exit_status(self) -> int:
        return 0 if self.passed else 1

    def text(self) -> str:
        d = self.description
        lines = [f"commissioning {d.name} ({d.source or 'shipped'}) on {self.bus}"]
        lines += [f"node 0x{i.node_id:02X}  device type 0x{i.device_type:08X}  vendor 0x{i.vendor_id:08X}  "
                  f"product 0x{i.product_code:X}  revision 0x{i.revision:X}  serial 0x{i.serial:X}"
                  for i in self.identities]
        lines += list(self.readings) + list(self.notes)
        lines += [defect.line for defect in self.defects]
        verdict = ("PASS: the bus is the description's robot; the agent may serve episodes"
                   if self.passed else f"FAIL: {len(self.defects)} defect(s); the agent will not serve episodes")
        return "\n".join([*lines, verdict])


def expected_nodes(description: RobotDescription) -> tuple[Expected, ...]:
    out = []
    for dev in description.devices:
        od = object_dictionary_file(dev.eds, dev.node_id)
        ident = Identity(dev.node_id, _default(od, 0x1000, 0), *(_default(od, 0x1018, s) for s in range(1, 5)))
        out.append(Expected(dev.name, dev.node_id, ident, eds_pdos(od), optional=dev.simulated_only))
    return tuple(out)


def _default(od, index: int, sub: int) -> int:  # noqa: ANN001
    entry = od[index]
    var = entry if not hasattr(entry, "subindices") else (entry[sub] if sub in entry else None)
    if var is None:
        return 0
    return int(var.value if var.value is not None else var.default or 0)


def commission(description: RobotDescription, bus: BusConfig, *, listen_s: float = 0.35,
               sdo_timeout_s: float = 0.3) -> Report:
    """Scan ``bus`` and compare it with ``description`` (see the package docstring)."""
    expected = expected_nodes(description)
    network = open_network(bus)
    try:
        heard = listen_heartbeats(network, listen_s)
        wanted = {e.node_id: e for e in expected}
        found: dict[int, Found] = {}
        clients: dict[int, canopen.RemoteNode] = {}
        for node_id in sorted(set(wanted) | heard):
            dev = _device(description, node_id)
            od = object_dictionary_file(dev.eds, dev.node_id) if dev is not None else None
            node = clients[node_id] = sdo_client(network, node_id, od, sdo_timeout_s)
            try:
                identity = read_identity(node.sdo, node_id)
                pdos = read_pdos(node.sdo) if dev is not None else ()
            except NoAnswer:
                identity, pdos = None, ()
            found[node_id] = Found(node_id, node_id in heard, identity, pdos)
        defects = check_nodes(expected, found)
        broken = {d.subject.split()[0] for d in defects}
        drives, readings = {}, []
        for axis in description.axes:
            if axis.node in broken or found.get(axis.node_id) is None or found[axis.node_id].identity is None:
                continue
            node, dev = clients[axis.node_id], description.device(axis.node)
            od = object_dictionary_file(dev.eds, dev.node_id)
            try:
                limits, reading = _axis(axis, node.sdo, od)
            except NoAnswer as exc:
                defects.append(Defect("missing node", f"{axis.node} 0x{axis.node_id:02X}",
                                      f"stopped answering while {axis.name} was read ({exc})"))
                continue
            drives[axis.name] = limits
            readings.append(reading)
        defects += check_limits(description, drives)
        idents = tuple(f.identity for _, f in sorted(found.items()) if f.identity is not None)
        robot_ids = tuple(i for i in idents if i.node_id in {d.node_id for d in description.robot_devices})
        return Report(description, bus.describe(), tuple(defects), idents, tuple(readings),
                      fingerprint(description, robot_ids))
    finally:
        network.disconnect()


def _device(description: RobotDescription, node_id: int) -> Device | None:
    try:
        return description.device(node_id)
    except KeyError:
        return None


def _axis(axis: Axis, sdo, od) -> tuple[DriveLimits, str]:  # noqa: ANN001
    """The drive's limits of one axis and a line with where it stands (profile by profile)."""
    if axis.profile == "cia402":
        return _cia402_axis(axis, sdo, od)
    return _board_axis(axis, sdo, od)


def _board_axis(axis: Axis, sdo, od) -> tuple[DriveLimits, str]:  # noqa: ANN001
    sub = axis.subindex

    def read(index: int, scale: float, unlimited: bool = False) -> float | None:
        if index not in od:
            return None
        raw = read_value(sdo, od, index, sub)
        var = od[index][sub] if hasattr(od[index], "subindices") else od[index]
        if raw is None or (unlimited and raw in (var.min, var.max)):
            return None  # a software position limit at the object's full range: none set
        return raw * scale

    current, velocity = read(0x2034, 1e-3), read(0x2035, 1e-3)
    lo, hi = read(0x2032, 1e-4, True), read(0x2033, 1e-4, True)
    source = {"current": f"0x2034:{sub}", "velocity": f"0x2035:{sub}", "position": f"0x2032/0x2033:{sub}"}
    position = None if lo is None and hi is None else (-math.inf if lo is None else lo,
                                                         math.inf if hi is None else hi)
    limits = DriveLimits(axis.name, current=current, velocity=velocity, position=position, source=source)
    q, qd, i = read(0x2000, 1e-4), read(0x2001, 1e-3), read(0x2002, 1e-3)
    status = read_value(sdo, od, 0x2010, 0) if 0x2010 in od else None
    return limits, (f"axis {axis.name:<15} position {_f(q)} rad  velocity {_f(qd)} rad/s  current {_f(i)} A  "
                    f"status 0x{int(status or 0):04X}  (limits: current {_f(current)} A, velocity "
                    f"{_f(velocity)} rad/s, position [{_f(lo)}, {_f(hi)}] rad)")


def _cia402_axis(axis: Axis, sdo, od) -> tuple[DriveLimits, str]:  # noqa: ANN001
    def read(index: int, sub: int = 0, unlimited: bool = False) -> int | None:
        if index not in od:
            return None
        raw = read_value(sdo, od, index, sub)
        var = od[index][sub] if hasattr(od[index], "subindices") else od[index]
        if unlimited and raw is not None and raw in (var.min, var.max, -(1 << 31), (1 << 31) - 1):
            return None  # a software position limit at the object's full range: none set
        return raw

    counted, revolutions = read(P402.ENCODER_RESOLUTION, 1), read(P402.ENCODER_RESOLUTION, 2)
    encoder = counted / revolutions if counted and revolutions else None
    increments = axis.encoder_counts or encoder or 1
    scaling = DriveScaling(gear=axis.gear, increments=float(increments),
                           rated_current=(read(P402.RATED_CURRENT) or 0) / 1000.0,
                           rated_torque=(read(P402.RATED_TORQUE) or 0) / 1000.0)
    max_current, max_torque = read(P402.MAX_CURRENT), read(P402.MAX_TORQUE)
    lo = read(P402.SOFTWARE_POSITION_LIMIT, 1, True)
    hi = read(P402.SOFTWARE_POSITION_LIMIT, 2, True)
    position = None if (lo is None and hi is None) or (lo == 0 and hi == 0) else (  # 0, 0: none (CiA 402)
        -math.inf if lo is None else scaling.position(lo), math.inf if hi is None else scaling.position(hi))
    limits = DriveLimits(
        axis.name,
        current=scaling.current(max_current) if max_current is not None and scaling.rated_current else None,
        torque=scaling.torque(max_torque) if max_torque is not None and scaling.rated_torque else None,
        position=position, encoder_counts=encoder,
        source={"current": "0x6073 x 0x6075", "torque": "0x6072 x 0x6076 x gear", "position": "0x607D",
                "encoder_counts": "0x608F:1 / 0x608F:2"})
    q, qd = read(P402.POSITION_ACTUAL), read(P402.VELOCITY_ACTUAL)
    status, volts = read(P402.STATUSWORD), read(P402.DC_LINK_VOLTAGE)
    return limits, (f"axis {axis.name:<15} position {_f(None if q is None else scaling.position(q))} rad  "
                    f"velocity {_f(None if qd is None else scaling.velocity(qd))} rad/s  statusword "
                    f"0x{int(status or 0):04X}  DC link {_f(None if volts is None else volts / 1000.0)} V  "
                    f"(limits: current {_f(limits.current)} A, torque {_f(limits.torque)} N m, position "
                    f"[{_f(position[0] if position else None)}, {_f(position[1] if position else None)}] rad)")


def _f(x: float | None) -> str:
    return "?" if x is None or not math.isfinite(x) else f"{x:.4g}"
