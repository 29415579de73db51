"""Reading a robot's bus, moving nothing: who answers, what they are, how their PDOs are mapped,
what their limits are and where their axes stand.

Every read is an SDO upload (CiA 301 expedited or segmented) or listening to heartbeats; no
NMT command, no PDO, no SYNC is sent, so the nodes stay in the state they were found in.

* ``listen_heartbeats(network, s)`` - node-ids heard (heartbeat or boot-up) within ``s``;
* ``read_identity(sdo)`` - 0x1000 device type and 0x1018 identity of one node;
* ``read_pdos(sdo)`` - the node's PDO communication and mapping objects (0x1400-0x15FF,
  0x1600-0x17FF, 0x1800-0x19FF, 0x1A00-0x1BFF), as many as it has;
* ``read_value(sdo, od, index, sub)`` - one object, decoded with the EDS's data type.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from protocol.can import cobid

MAX_PDOS = 4
"""PDOs per direction read back (CiA 301 pre-defined connection set: four of each)."""


class NoAnswer(Exception):
    """The node did not answer an SDO upload (absent, or not a CANopen node)."""


@dataclass(frozen=True)
class Identity:
    """What a node says it is: 0x1000 and 0x1018:1-4."""
    node_id: int
    device_type: int
    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def as_list(self) -> list[int]:
        return [self.node_id, self.device_type, self.vendor_id, self.product_code, self.revision, self.serial]


@dataclass(frozen=True)
class PdoMap:
    """One PDO as a node (or its EDS) configures it: ``direction`` seen from the node (``tpdo``
    it transmits, ``rpdo`` it receives), COB-ID (bit 31 set: not valid), transmission type and
    the mapping words (index << 16 | sub << 8 | bits) in order."""
    direction: str
    number: int
    cob_id: int
    transmission_type: int
    entries: tuple[int, ...]

    @property
    def enabled(self) -> bool:
        return not self.cob_id & (1 << 31)

    def describe(self) -> str:
        if not self.enabled:
            return "disabled"
        maps = " ".join(f"{w >> 16:04X}:{(w >> 8) & 0xFF}/{w & 0xFF}" for w in self.entries)
        return f"COB-ID 0x{self.cob_id & 0x7FF:03X} type {self.transmission_type} [{maps}]"


_BASES = (("rpdo", 0x1400, 0x1600), ("tpdo", 0x1800, 0x1A00))


def _u(data: bytes) -> int:
    return int.from_bytes(data[:4].ljust(4, b"\0"), "little")


def upload(sdo: canopen.sdo.SdoClient, index: int, subindex: int) -> bytes | None:
    """The raw bytes of ``index:subindex`` (``None``: the node aborted: no such object)."""
    try:
        return sdo.upload(index, subindex)
    except SdoAbortedError:
        return None
    except SdoCommunicationError as exc:
        raise NoAnswer(f"0x{index:04X}:{subindex}: {exc}") from None


def read_identity(sdo: canopen.sdo.SdoClient, node_id: int) -> Identity:
    """0x1000 and 0x1018:1-4 (a missing 0x1018 sub-index reads as 0). ``NoAnswer``: no node."""
    device_type = upload(sdo, 0x1000, 0)
    if device_type is None:
        raise NoAnswer("0x1000 aborted: not a CiA 301 node")
    ident = [upload(sdo, 0x1018, sub) for sub in range(1, 5)]
    return Identity(node_id, _u(device_type), *(_u(v) if v is not None else 0 for v in ident))


def read_pdos(sdo: canopen.sdo.SdoClient) -> tuple[PdoMap, ...]:
    """Every PDO the node has among the first ``MAX_PDOS`` of each direction."""
    out = []
    for direction, comm, mapping in _BASES:
        for n in range(MAX_PDOS):
            cob = upload(sdo, comm + n, 1)
            if cob is None:
                continue
            trans = upload(sdo, comm + n, 2)
            count = upload(sdo, mapping + n, 0)
            words = tuple(_u(upload(sdo, mapping + n, s) or b"") for s in range(1, (count or b"\0")[0] + 1))
            out.append(PdoMap(direction, n + 1, _u(cob), (trans or b"\0")[0], words))
    return tuple(out)


def eds_pdos(od: canopen.ObjectDictionary) -> tuple[PdoMap, ...]:
    """The same maps as the EDS (its default values) gives them."""
    def value(index: int, sub: int) -> int:
        entry = od[index]
        var = entry if sub == 0 and not hasattr(entry, "subindices") else entry[sub]
        return int(var.value if var.value is not None else var.default or 0)

    out = []
    for direction, comm, mapping in _BASES:
        for n in range(MAX_PDOS):
            if comm + n not in od:
                continue
            count = value(mapping + n, 0)
            out.append(PdoMap(direction, n + 1, value(comm + n, 1), value(comm + n, 2),
                              tuple(value(mapping + n, s) for s in range(1, count + 1))))
    return tuple(out)


def read_value(sdo: canopen.sdo.SdoClient, od: canopen.ObjectDictionary, index: int,
               subindex: int) -> int | float | None:
    """One object decoded with the EDS's data type (``None``: the node has no such object)."""
    entry = od[index]
    var = entry if not hasattr(entry, "subindices") else entry[subindex]
    data = upload(sdo, index, subindex)
    return None if data is None else var.decode_raw(data)


def listen_heartbeats(network: canopen.Network, seconds: float) -> set[int]:
    """Node-ids whose heartbeat or boot-up message (COB-ID 0x700 + id) was heard."""
    heard: set[int] = set()
    lock = threading.Lock()

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        with lock:
            heard.add(can_id - 0x700)

    ids = range(1, 128)
    for node_id in ids:
        network.subscribe(cobid.heartbeat(node_id), on_frame)
    try:
        time.sleep(seconds)  # listening for a fixed window is the point: heartbeats are periodic
    finally:
        for node_id in ids:
            network.unsubscribe(cobid.heartbeat(node_id), on_frame)
    with lock:
        return set(heard)


def sdo_client(network: canopen.Network, node_id: int, od: canopen.ObjectDictionary | None,
               timeout_s: float) -> canopen.RemoteNode:
    """A node to upload from (its EDS's dictionary, or an empty one for a node not described)."""
    node = canopen.RemoteNode(node_id, od if od is not None else canopen.ObjectDictionary())
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = timeout_s
    return node


def identities(nodes: Iterable[tuple[int, canopen.sdo.SdoClient]], attempts: int = 3) -> list[Identity]:
    """The identity of every node that answers within ``attempts`` tries (the others are left out)."""
    out = []
    for node_id, sdo in nodes:
        for _ in range(attempts):
            try:
                out.append(read_identity(sdo, node_id))
                break
            except NoAnswer:
                continue
    return out


