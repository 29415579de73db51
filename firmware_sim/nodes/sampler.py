"""One TPDO sampler for the whole simulated robot: every node's synchronous TPDOs packed from
one telemetry row per SYNC (``devices.telemetry_row``: the axes' counts computed for all boards
at once, the IMU's counts, the sampling device's status word in the last slot), instead of
each node sampling its application into its own value dict and packing from there.

The frames, their order and their bytes are those the nodes would send themselves
(``SlaveNode.transmit_tpdos``): the same counts, the same structs, node by node in the
robot's device order, each node's due TPDOs in its own order.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from firmware_sim.nodes.base import SlaveNode, TpdoLayout, tuple_getter
from firmware_sim.nodes.devices import STATUS_SLOT, AxisCounts, DeviceApp


@dataclass(frozen=True)
class NodePlan:
    """A node with TPDOs; per TPDO (the node's order) its layout, its struct's ``pack`` and the
    picker of its values from a telemetry row."""

    node: SlaveNode
    app: DeviceApp
    tpdos: tuple[tuple[TpdoLayout, Callable[..., bytes], Callable[[list[int]], tuple[int, ...]]], ...]


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
            tpdos = []
            for tpdo in node.tpdo_layouts:
                missing = [key for key in tpdo.keys if key not in app.slots]
                if missing:
                    raise ValueError(f"node {node.id:#x}: TPDO {tpdo.cob_id:#x} maps objects "
                                     f"the device does not sample: {missing}")
                tpdos.append((tpdo, tpdo.layout.pack, tuple_getter(tuple(app.slots[key] for key in tpdo.keys))))
            plans.append(NodePlan(node, app, tuple(tpdos)))
        self._plans = tuple(plans)

    def pack(self, row: list[int], axes: AxisCounts, out: list[tuple[int, bytes]]) -> None:
        """Append ``(COB-ID, data)`` of every TPDO due at this SYNC to ``out``; ``row`` is this
        SYNC's telemetry row (its status slot is overwritten), ``axes`` its axis counts."""
        for plan in self._plans:
            count = plan.node.count_sync()
            if not count:
                continue
            row[STATUS_SLOT] = plan.app.status_word(axes)
            for tpdo, pack, pick in plan.tpdos:
                if tpdo.due(count):
                    out.append((tpdo.cob_id, pack(*pick(row))))
