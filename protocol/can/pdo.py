"""PDO maps of the devices, read from the EDS files (never restated in code).

``pdo_maps(device)`` gives every RPDO/TPDO of a device as ``PdoSpec``: its COB-ID,
transmission type and mapped entries (index, sub-index, bit length, name). The agent, the
simulator nodes, the bus-load budget and docs/protocol.md all derive from this.
``pdo_struct(spec)`` is the frame layout compiled once (``struct``), what both sides pack and
unpack cyclic PDOs with instead of canopen's per-variable encoding.
"""
from __future__ import annotations

import functools
import struct
from dataclasses import dataclass
from typing import Literal

from canopen.objectdictionary import ODRecord, ODVariable

from protocol.can.devices import DEVICES, Device, object_dictionary
from protocol.robot.eds import object_dictionary_file

Direction = Literal["tpdo", "rpdo"]


@dataclass(frozen=True)
class PdoEntry:
    index: int
    subindex: int
    bits: int
    name: str


@dataclass(frozen=True)
class PdoSpec:
    """One PDO of one device. ``direction`` is seen from the device: a TPDO is transmitted by
    the device (telemetry), an RPDO received (commands). ``transmission_type`` 1..240 means
    synchronous, sent/applied every ``transmission_type``-th SYNC. ``eds`` is the EDS file
    the map was read from (``Device.eds``)."""
    device: str
    node_id: int
    direction: Direction
    number: int
    cob_id: int
    transmission_type: int
    entries: tuple[PdoEntry, ...]
    eds: str = ""
    event_timer_ms: int = 0
    """An event-driven TPDO's (transmission type 254/255) event timer (0x18xx:5): it is sent
    at least this often; 0: none, or a PDO that is not valid (COB-ID bit 31) or maps nothing."""

    @property
    def length(self) -> int:
        """Data bytes in the frame."""
        return (sum(e.bits for e in self.entries) + 7) // 8

    @property
    def synchronous(self) -> bool:
        return 1 <= self.transmission_type <= 240

    @property
    def keys(self) -> tuple[tuple[int, int], ...]:
        """(index, sub-index) of every mapped object, in frame order."""
        return tuple((e.index, e.subindex) for e in self.entries)


def _object(od, index: int, subindex: int) -> ODVariable:  # noqa: ANN001
    entry = od[index]
    return entry if subindex == 0 and isinstance(entry, ODVariable) else entry[subindex]


@functools.cache
def pdo_struct(spec: PdoSpec) -> struct.Struct:
    """Little-endian layout of ``spec``'s frame: one field per entry, in map order, with the
    integer type of the mapped object (``pack(*raw_values)`` / ``unpack(frame)``).

    Raises:
        ValueError: an entry that is not a whole byte-aligned integer of its object's size.
    """
    od = object_dictionary_file(spec.eds, spec.node_id)
    fmt = "<"
    for e in spec.entries:
        var = _object(od, e.index, e.subindex)
        field = var.STRUCT_TYPES[var.data_type].format.lstrip("<")
        if struct.calcsize("<" + field) * 8 != e.bits:
            raise ValueError(f"{spec.device} PDO {spec.number}: 0x{e.index:04X}:{e.subindex} maps "
                             f"{e.bits} bits of a {field!r} object")
        fmt += field
    return struct.Struct(fmt)


def _value(var: ODVariable) -> int:
    return int(var.value if var.value is not None else var.default)


def pdo_maps(dev: Device) -> tuple[PdoSpec, ...]:
    od = object_dictionary(dev)
    specs: list[PdoSpec] = []
    for direction, comm_base, map_base in (("rpdo", 0x1400, 0x1600), ("tpdo", 0x1800, 0x1A00)):
        for n in range(512):
            if comm_base + n not in od:
                break
            comm: ODRecord = od[comm_base + n]
            mapping: ODRecord = od[map_base + n]
            entries = []
            for sub in range(1, _value(mapping[0]) + 1):
                word = _value(mapping[sub])
                index, subindex, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
                target = _object(od, index, subindex)
                entries.append(PdoEntry(index, subindex, bits, target.name))
            cob_word, trans = _value(comm[1]), _value(comm[2])
            timer = _value(comm[5]) if direction == "tpdo" and 5 in comm.subindices else 0
            if cob_word & 0x8000_0000 or not entries or trans < 254:
                timer = 0
            specs.append(PdoSpec(dev.name, dev.node_id, direction, n + 1,
                                 cob_word & 0x7FF, trans, tuple(entries), dev.eds, timer))
    return tuple(specs)


def timed_pdos(devices: tuple[Device, ...] = DEVICES) -> tuple[PdoSpec, ...]:
    """Every event-driven TPDO with an event timer of the given devices (periodic traffic
    beside the SYNC schedule: a CiA 402 drive's statusword and mode every 100 ms)."""
    return tuple(p for d in devices for p in pdo_maps(d) if p.event_timer_ms > 0)


def cyclic_pdos(devices: tuple[Device, ...] = DEVICES) -> tuple[PdoSpec, ...]:
    """Every synchronous PDO of the given devices (the schedule of one SYNC period, without
    SYNC itself); a description's are ``cyclic_pdos(description.devices)``."""
    return tuple(p for d in devices for p in pdo_maps(d) if p.synchronous)
