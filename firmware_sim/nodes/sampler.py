"""One TPDO sampler for the whole simulated robot: every node's synchronous TPDOs packed from
one telemetry row per SYNC (``devices.telemetry_row``: the axes' counts computed for all boards
at once, the IMU's counts, the sampling device's status word in the last slot), instead of
each node sampling its application into its own value dict and packing from there.

The frames, their order and their bytes are those the nodes would send themselves
(``SlaveNode.transmit_tpdos``): the same counts, the same structs, node by node in the
robot's device order, each node's due TPDOs in its own order.
"""
from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from firmware_sim.nodes.base import SlaveNode, TpdoLayout, tuple_getter
from firmware_sim.nodes.devices import STATUS_SLOT, AxisCounts, DeviceApp


Picker = Callable[[list[int]], tuple[int, ...]]


@dataclass(frozen=True)
class NodePlan:
    """A node with TPDOs; per TPDO (the node's order) its layout, its struct's ``pack`` and the
    picker of its values from a telemetry row. When every TPDO of the node goes out at every
    SYNC (transmission type 1), ``whole`` packs them all at once (their structs' fields in
    frame order: the frames' bytes one after the other, ``"<"`` has no padding), ``pick``
    their values, and ``cuts`` gives each frame's COB-ID and its bytes' range."""

    node: SlaveNode
    app: DeviceApp
    tpdos: tuple[tuple[TpdoLayout, Callable[..., bytes], Picker], ...]
    whole: Callable[..., bytes] | None = None
    pick: Picker | None = None
    cuts: tuple[tuple[int, int, int], ...] = ()


def whole_node(tpdos: Sequence[TpdoLayout], slots: Sequence[tuple[int, ...]]) -> tuple[
        Callable[..., bytes], Picker, tuple[tuple[int, int, int], ...]]:
    """One struct for the frames ``tpdos`` (little-endian layouts, values at ``slots`` of a
    telemetry row, one tuple per TPDO): its ``pack``, the picker of all their values and each
    frame's (COB-ID, start, end) in the packed bytes."""
    layout = struct.Struct("<" + "".join(t.layout.format.lstrip("<") for t in tpdos))
    cuts, at = [], 0
    for t in tpdos:
        cuts.append((t.cob_id, at, at + t.layout.size))
        at += t.layout.size
    return layout.pack, tuple_getter(tuple(slot for group in slots for slot in group)), tuple(cuts)


class TpdoSampler:
    """Packs the due TPDOs of ``nodes`` (connected, applications ``DeviceApp``) from one row.

    Raises ``ValueError`` at construction when a TPDO maps an object the node's application
    does not sample (its ``slots``)."""

    def __init__(self, nodes: Sequence[SlaveNode]) -> None:
        plans = []
        for node in nodes:
            app = node.app
            if not node.tpdo_layouts:
                continue
            if not isinstance(app, DeviceApp):
                raise ValueError(f"node {node.id:#x}: its application samples no telemetry row")
            tpdos, slots = [], []
            for tpdo in node.tpdo_layouts:
                missing = [key for key in tpdo.keys if key not in app.slots]
                if missing:
                    raise ValueError(f"node {node.id:#x}: TPDO {tpdo.cob_id:#x} maps objects "
                                     f"the device does not sample: {missing}")
                slots.append(tuple(app.slots[key] for key in tpdo.keys))
                tpdos.append((tpdo, tpdo.layout.pack, tuple_getter(slots[-1])))
            every_sync = all(tpdo.every == 1 and tpdo.layout.format.startswith("<") for tpdo in node.tpdo_layouts)
            whole = whole_node(node.tpdo_layouts, slots) if every_sync else (None, None, ())
            plans.append(NodePlan(node, app, tuple(tpdos), *whole))
        self._plans = tuple(plans)

    def pack(self, row: list[int], axes: AxisCounts, out: list[tuple[int, bytes]]) -> None:
        """Append ``(COB-ID, data)`` of every TPDO due at this SYNC to ``out``; ``row`` is this
        SYNC's telemetry row (its status slot is overwritten), ``axes`` its axis counts."""
        for plan in self._plans:
            count = plan.node.count_sync()
            if not count:
                continue
            row[STATUS_SLOT] = plan.app.status_word(axes)
            if plan.whole is not None:  # every TPDO due: one pack, cut into the frames
                data = plan.whole(*plan.pick(row))
                out += [(cob_id, data[start:end]) for cob_id, start, end in plan.cuts]
                continue
            for tpdo, pack, pick in plan.tpdos:
                if tpdo.due(count):
                    out.append((tpdo.cob_id, pack(*pick(row))))
