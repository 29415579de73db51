"""COB-ID assignment (CiA 301 pre-defined connection set), in one place.

Nothing else in the project computes ``0x580 + node_id``: call these instead.
"""
from __future__ import annotations

from dataclasses import dataclass

NMT = 0x000
SYNC = 0x080
TIME = 0x100

_EMCY, _TPDO, _RPDO, _SDO_TX, _SDO_RX, _HEARTBEAT = 0x080, 0x180, 0x200, 0x580, 0x600, 0x700


def _check(node_id: int) -> int:
    if not 1 <= node_id <= 127:
        raise ValueError(f"CANopen node-id must be 1..127, got {node_id}")
    return node_id


def emcy(node_id: int) -> int:
    return _EMCY + _check(node_id)


def tpdo(n: int, node_id: int) -> int:
    """COB-ID of TPDO ``n`` (1..4) of a node."""
    if not 1 <= n <= 4:
        raise ValueError(f"pre-defined TPDO number must be 1..4, got {n}")
    return _TPDO + 0x100 * (n - 1) + _check(node_id)


def rpdo(n: int, node_id: int) -> int:
    """COB-ID of RPDO ``n`` (1..4) of a node."""
    if not 1 <= n <= 4:
        raise ValueError(f"pre-defined RPDO number must be 1..4, got {n}")
    return _RPDO + 0x100 * (n - 1) + _check(node_id)


def sdo_tx(node_id: int) -> int:
    """Server -> client (the node's SDO responses)."""
    return _SDO_TX + _check(node_id)


def sdo_rx(node_id: int) -> int:
    """Client -> server (requests to the node)."""
    return _SDO_RX + _check(node_id)


def heartbeat(node_id: int) -> int:
    return _HEARTBEAT + _check(node_id)


@dataclass(frozen=True)
class CobIdInfo:
    """What a COB-ID means: ``function`` (``"NMT"``, ``"SYNC"``, ``"EMCY"``, ``"TPDO3"``, ...)
    and the node it belongs to (``None`` for broadcast objects)."""
    function: str
    node_id: int | None


def classify(cob_id: int) -> CobIdInfo:
    """Inverse of the functions above, for bus monitors and logs."""
    if cob_id == NMT:
        return CobIdInfo("NMT", None)
    if cob_id == SYNC:
        return CobIdInfo("SYNC", None)
    if cob_id == TIME:
        return CobIdInfo("TIME", None)
    base, node = cob_id & 0x780, cob_id & 0x7F
    if node == 0:
        return CobIdInfo(f"0x{cob_id:03X}", None)
    names = {_EMCY: "EMCY", _SDO_TX: "SDO-TX", _SDO_RX: "SDO-RX", _HEARTBEAT: "HEARTBEAT"}
    if base in names:
        return CobIdInfo(names[base], node)
    if base in (0x180, 0x280, 0x380, 0x480):
        return CobIdInfo(f"TPDO{(base - 0x180) // 0x100 + 1}", node)
    if base in (0x200, 0x300, 0x400, 0x500):
        return CobIdInfo(f"RPDO{(base - 0x200) // 0x100 + 1}", node)
    return CobIdInfo(f"0x{cob_id:03X}", node)
