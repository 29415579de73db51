"""Generate the DBC of the bus of every shipped robot description (protocol/robots/<name>.toml
-> protocol/can/dbc/<name>.dbc) from its nodes and their EDS files: every PDO of every device
with its signals in physical units, and the CANopen frames around them (NMT, SYNC, heartbeats,
EMCY) named.

With it `cantools decode`, asammdf and PlotJuggler decode the traces of
``ersac-hil agent --record-can`` (BLF/ASC) without reading the EDS files. Each signal's factor
and unit are the EDS ``Factor``/``Unit`` of the mapped object (``value = raw * factor``, offset
0); codes and bit words keep factor 1 and say what they mean in their comment. PDOs are
little-endian (Intel), no multiplexing. Run `python tools/gen_dbc.py` after changing the EDS
files and commit the result; `tests/protocol/test_dbc.py` fails when the committed file differs
from what this writes (`--check`).
"""
from __future__ import annotations

import math
import re
import sys
from collections import OrderedDict
from pathlib import Path

from canopen.nmt import NMT_STATES
from canopen.objectdictionary import ODVariable
from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from protocol.can import cobid
from protocol.can.devices import Device, object_dictionary
from protocol.can.objects import Control, EmcyCode, Index, Status
from protocol.can.pdo import PdoEntry, PdoSpec, pdo_maps
from protocol.robot import RobotDescription, load_description
from protocol.robot.load import shipped_names

OUT = Path(__file__).resolve().parents[1] / "protocol" / "can" / "dbc"
AGENT = "agent"

NMT_COMMANDS = {1: "start", 2: "stop", 128: "enter_pre_operational", 129: "reset_node",
                130: "reset_communication"}
"""CiA 301 NMT command specifiers."""


BIT_WORDS = {Index.STATUS: Status, Index.CONTROL: Control}
"""Bit words whose bits the signal comment lists."""


def snake(text: str) -> str:
    return re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower()


def _choices(table: dict[int, str]) -> OrderedDict:
    return OrderedDict(sorted((code, snake(name)) for code, name in table.items()))


def _cia402_scale(description: RobotDescription, dev: Device, index: int) -> tuple[float, str] | None:
    """Joint-side SI scaling of a CiA 402 drive's position, velocity, torque and current
    objects (their EDS counts are drive units): encoder increments and gear from the
    description's axis, rated torque/current (0x6076 mN m, 0x6075 mA) from the EDS."""
    axis = next((a for a in description.axes if a.node == dev.name), None)
    if axis is None or axis.profile != "cia402":
        return None
    od = object_dictionary(dev)
    if index in (0x6064, 0x607A, 0x606C) and axis.encoder_counts:
        per_count = 2 * math.pi / (axis.encoder_counts * axis.gear)
        return per_count, "rad/s" if index == 0x606C else "rad"
    if index in (0x6071, 0x6077) and 0x6076 in od:
        return float(od[0x6076].default) * 1e-6 * axis.gear, "N m"
    if index == 0x6078 and 0x6075 in od:
        return float(od[0x6075].default) * 1e-6, "A"
    return None


def _signal(description: RobotDescription, dev: Device, entry: PdoEntry, start: int,
            receivers: list[str]) -> Signal:
    od = object_dictionary(dev)
    obj = od[entry.index]
    var = obj if isinstance(obj, ODVariable) else obj[entry.subindex]
    if isinstance(obj, ODVariable):
        name = snake(obj.name)
    else:  # an ARRAY over the device's axes: the robot-level joint name first
        joints = dev.joints or dev.axes
        name = f"{joints[entry.subindex - 1]}_{snake(obj.name)}"
    signed = var.data_type in (0x02, 0x03, 0x04)
    factor, unit = (float(var.factor), var.unit) if var.unit else (1.0, "")
    drive = _cia402_scale(description, dev, entry.index)
    if drive is not None:
        factor, unit = drive
    raw_min = var.min if var.min is not None else (-(1 << (entry.bits - 1)) if signed else 0)
    raw_max = var.max if var.max is not None else ((1 << (entry.bits - 1)) - 1 if signed else (1 << entry.bits) - 1)
    comment = f"0x{entry.index:04X}:{entry.subindex} {var.name}"
    bits = BIT_WORDS.get(entry.index)
    if bits is not None and dev.profile != "cia402":
        comment += " (bits: " + ", ".join(f"{b.value.bit_length() - 1} {b.name}" for b in bits) + ")"
    elif drive is not None:
        comment += f" (EDS: {var.description}; joint side)"
    elif not unit and var.description:
        comment += f" ({var.description})"
    return Signal(name, start, entry.bits, "little_endian", signed,
                  conversion=BaseConversion.factory(scale=factor, offset=0),
                  minimum=raw_min * factor, maximum=raw_max * factor, unit=unit or None,
                  comment=comment, receivers=receivers)


def _pdo(description: RobotDescription, dev: Device, spec: PdoSpec, cycle_ms: int) -> Message:
    tpdo = spec.direction == "tpdo"
    sender, receiver = (dev.name, AGENT) if tpdo else (AGENT, dev.name)
    signals, start = [], 0
    for entry in spec.entries:
        signals.append(_signal(description, dev, entry, start, [receiver]))
        start += entry.bits
    when = "synchronous, every SYNC" if spec.synchronous else f"transmission type {spec.transmission_type}"
    return Message(spec.cob_id, f"{dev.name}_{spec.direction.upper()}{spec.number}", spec.length, signals,
                   comment=f"{spec.direction.upper()}{spec.number} of {dev.name} (node 0x{dev.node_id:02X}), {when}",
                   senders=[sender], cycle_time=cycle_ms if spec.synchronous else None)


def _heartbeat(name: str, node_id: int) -> Message:
    state = Signal("nmt_state", 0, 7, conversion=BaseConversion.factory(choices=_choices(NMT_STATES)),
                   comment="NMT state (0: boot-up message)", receivers=[])
    return Message(cobid.heartbeat(node_id), f"heartbeat_{name}", 1, [state],
                   comment=f"Heartbeat of {name} (node 0x{node_id:02X})", senders=[name])


def _emcy(dev: Device) -> Message:
    signals = [
        Signal("error_code", 0, 16, conversion=BaseConversion.factory(choices=_choices(
            {int(c): c.name for c in EmcyCode})), comment="CiA 301 EMCY error code", receivers=[AGENT]),
        Signal("error_register", 16, 8, comment="object 0x1001 at the time of the error", receivers=[AGENT]),
        Signal("manufacturer_error", 24, 40, comment="manufacturer-specific error field", receivers=[AGENT]),
    ]
    return Message(cobid.emcy(dev.node_id), f"emcy_{dev.name}", 8, signals,
                   comment=f"EMCY of {dev.name} (node 0x{dev.node_id:02X})", senders=[dev.name])


def database(description: RobotDescription) -> Database:
    """The DBC of ``description``'s bus (its devices, bit rate, SYNC period, agent node-id)."""
    devices, bus = description.devices, description.bus
    cycle_ms = round(bus.sync_period_ms)
    agent_node_id = bus.agent_node_id
    nodes = [Node(AGENT, comment=f"NMT master and SYNC producer (heartbeat node 0x{agent_node_id:02X})")]
    nodes += [Node(d.name, comment=f"node 0x{d.node_id:02X}, {d.eds}"
                   + (" (simulated benches only)" if d.simulated_only else "")) for d in devices]
    nmt = Message(cobid.NMT, "nmt", 2, [
        Signal("command", 0, 8, conversion=BaseConversion.factory(choices=OrderedDict(sorted(NMT_COMMANDS.items()))),
               receivers=[d.name for d in devices]),
        Signal("node_id", 8, 8, comment="0: every node", receivers=[d.name for d in devices])],
        comment="NMT node control", senders=[AGENT])
    sync = Message(cobid.SYNC, "sync", 0, [], comment="SYNC (no counter): one control cycle",
                   senders=[AGENT], cycle_time=cycle_ms)
    messages = [nmt, sync]
    for d in devices:
        messages += [_pdo(description, d, p, cycle_ms) for p in pdo_maps(d) if p.entries]
        if Index.COB_ID_EMCY in object_dictionary(d):
            messages.append(_emcy(d))
        messages.append(_heartbeat(d.name, d.node_id))
    messages.append(_heartbeat(AGENT, agent_node_id))
    messages.sort(key=lambda m: m.frame_id)
    return Database(messages=messages, nodes=nodes, buses=[Bus(description.name, baudrate=bus.bitrate)],
                    version=f"{description.name}: generated by tools/gen_dbc.py from its description and EDS files")


def render(description: RobotDescription) -> str:
    return database(description).as_dbc_string().replace("\r\n", "\n")


def main(check: bool = False) -> int:
    from generated import write_or_check  # tools/, beside this script
    files = {OUT / f"{stem}.dbc": render(load_description(stem)) for stem in shipped_names()}
    return write_or_check(files, check, "DBC files", "gen_dbc.py")


if __name__ == "__main__":
    sys.exit(main(check="--check" in sys.argv))
