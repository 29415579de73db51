"""Generate the DBC of the bus (protocol/can/dbc/<robot>.dbc) from the EDS files: every PDO of
every device with its signals in physical units, and the CANopen frames around them (NMT, SYNC,
heartbeats, EMCY) named.

With it `cantools decode`, asammdf and PlotJuggler decode the traces of
``ersac-hil agent --record-can`` (BLF/ASC) without reading the EDS files. Each signal's factor
and unit are the EDS ``Factor``/``Unit`` of the mapped object (``value = raw * factor``, offset
0); codes and bit words keep factor 1 and say what they mean in their comment. PDOs are
little-endian (Intel), no multiplexing. Run `python tools/gen_dbc.py` after changing the EDS
files and commit the result; `tests/protocol/test_dbc.py` fails when the committed file differs
from what this writes (`--check`).
"""
from __future__ import annotations

import re
import sys
from collections import OrderedDict
from pathlib import Path

from canopen.nmt import NMT_STATES
from canopen.objectdictionary import ODVariable
from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from protocol.can import cobid
from protocol.can.busconfig import DEFAULT_BITRATE
from protocol.can.devices import AGENT_NODE_ID, DEVICES, Device, object_dictionary
from protocol.can.objects import Control, EmcyCode, Index, Status
from protocol.can.pdo import PdoEntry, PdoSpec, pdo_maps

OUT = Path(__file__).resolve().parents[1] / "protocol" / "can" / "dbc"
AGENT = "agent"
SYNC_PERIOD_MS = 5
"""The cycle time written for the synchronous PDOs and SYNC (GenMsgCycleTime)."""

NMT_COMMANDS = {1: "start", 2: "stop", 128: "enter_pre_operational", 129: "reset_node",
                130: "reset_communication"}
"""CiA 301 NMT command specifiers."""


BIT_WORDS = {Index.STATUS: Status, Index.CONTROL: Control}
"""Bit words whose bits the signal comment lists."""


def snake(text: str) -> str:
    return re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower()


def _choices(table: dict[int, str]) -> OrderedDict:
    return OrderedDict(sorted((code, snake(name)) for code, name in table.items()))


def _signal(dev: Device, entry: PdoEntry, start: int, receivers: list[str]) -> Signal:
    od = object_dictionary(dev)
    obj = od[entry.index]
    var = obj if isinstance(obj, ODVariable) else obj[entry.subindex]
    if isinstance(obj, ODVariable):
        name = snake(obj.name)
    else:  # an ARRAY over the device's axes: the robot-level joint name first
        joints = dev.joints or dev.axes
        name = f"{joints[entry.subindex - 1]}_{snake(obj.name)}"
    signed = var.data_type in (0x02, 0x03, 0x04)
    factor = float(var.factor) if var.unit else 1.0
    raw_min = var.min if var.min is not None else (-(1 << (entry.bits - 1)) if signed else 0)
    raw_max = var.max if var.max is not None else ((1 << (entry.bits - 1)) - 1 if signed else (1 << entry.bits) - 1)
    comment = f"0x{entry.index:04X}:{entry.subindex} {var.name}"
    bits = BIT_WORDS.get(entry.index)
    if bits is not None:
        comment += " (bits: " + ", ".join(f"{b.value.bit_length() - 1} {b.name}" for b in bits) + ")"
    elif not var.unit and var.description:
        comment += f" ({var.description})"
    return Signal(name, start, entry.bits, "little_endian", signed,
                  conversion=BaseConversion.factory(scale=factor, offset=0),
                  minimum=raw_min * factor, maximum=raw_max * factor, unit=var.unit or None,
                  comment=comment, receivers=receivers)


def _pdo(spec: PdoSpec) -> Message:
    dev = next(d for d in DEVICES if d.name == spec.device)
    tpdo = spec.direction == "tpdo"
    sender, receiver = (dev.name, AGENT) if tpdo else (AGENT, dev.name)
    signals, start = [], 0
    for entry in spec.entries:
        signals.append(_signal(dev, entry, start, [receiver]))
        start += entry.bits
    when = "synchronous, every SYNC" if spec.synchronous else f"transmission type {spec.transmission_type}"
    return Message(spec.cob_id, f"{dev.name}_{spec.direction.upper()}{spec.number}", spec.length, signals,
                   comment=f"{spec.direction.upper()}{spec.number} of {dev.name} (node 0x{dev.node_id:02X}), {when}",
                   senders=[sender], cycle_time=SYNC_PERIOD_MS if spec.synchronous else None)


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


def database(devices: tuple[Device, ...] = DEVICES, bus_name: str = "ubot5") -> Database:
    nodes = [Node(AGENT, comment=f"NMT master and SYNC producer (heartbeat node 0x{AGENT_NODE_ID:02X})")]
    nodes += [Node(d.name, comment=f"node 0x{d.node_id:02X}, {d.eds}"
                   + (" (simulated benches only)" if d.simulated_only else "")) for d in devices]
    nmt = Message(cobid.NMT, "nmt", 2, [
        Signal("command", 0, 8, conversion=BaseConversion.factory(choices=OrderedDict(sorted(NMT_COMMANDS.items()))),
               receivers=[d.name for d in devices]),
        Signal("node_id", 8, 8, comment="0: every node", receivers=[d.name for d in devices])],
        comment="NMT node control", senders=[AGENT])
    sync = Message(cobid.SYNC, "sync", 0, [], comment="SYNC (no counter): one control cycle",
                   senders=[AGENT], cycle_time=SYNC_PERIOD_MS)
    messages = [nmt, sync]
    for d in devices:
        messages += [_pdo(p) for p in pdo_maps(d)]
        if Index.COB_ID_EMCY in object_dictionary(d):
            messages.append(_emcy(d))
        messages.append(_heartbeat(d.name, d.node_id))
    messages.append(_heartbeat(AGENT, AGENT_NODE_ID))
    messages.sort(key=lambda m: m.frame_id)
    return Database(messages=messages, nodes=nodes, buses=[Bus(bus_name, baudrate=DEFAULT_BITRATE)],
                    version="generated by tools/gen_dbc.py from protocol/can/eds")


def render(devices: tuple[Device, ...] = DEVICES, bus_name: str = "ubot5") -> str:
    return database(devices, bus_name).as_dbc_string().replace("\r\n", "\n")


TARGETS: dict[str, tuple[Device, ...]] = {"ubot5": DEVICES}
"""One DBC per robot: file stem -> its devices."""


def main(check: bool = False) -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    stale = []
    for stem, devices in TARGETS.items():
        text, path = render(devices, stem), OUT / f"{stem}.dbc"
        if check:
            if not path.exists() or path.read_text() != text:
                stale.append(path.name)
        else:
            path.write_text(text)
    if stale:
        print("stale DBC files (run python tools/gen_dbc.py):", ", ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(check="--check" in sys.argv))
