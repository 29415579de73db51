"""A node's RPDOs received between two SYNCs, and what they change at the SYNC.

CiA 301 synchronous RPDOs take effect at the next SYNC: until then only the latest frame of
each RPDO counts. ``RpdoInbox`` keeps those frames as they arrive (bytes, nothing unpacked)
and, at the SYNC, merges them into the node's application values in the order the RPDOs first
arrived, returning the values that changed. A frame equal to the one its RPDO applied last
changes nothing and is not unpacked: a cyclic command that holds still (the arm setpoints
of a whole bracing episode) costs a bytes comparison a cycle.

That is the merge of every received value by object, key order of first arrival, latest value
winning, compared against the values before the SYNC (what ``SlaveNode`` did with a dict of
pending values), because a node's RPDOs map distinct objects (checked at construction) and
only ``take`` writes the RPDO-mapped values; whoever else changes or removes one of them
(a reset) calls ``forget_applied``.
"""
from __future__ import annotations

from collections.abc import Sequence

from protocol.can.pdo import PdoSpec, pdo_struct

Key = tuple[int, int]


class RpdoInbox:
    """The RPDOs ``specs`` of one node, slot ``k`` for ``specs[k]``. Not locked: the node
    calls ``store``, ``take`` and ``discard`` under its own lock.

    Raises ``ValueError`` at construction when two mapped entries name the same object."""

    def __init__(self, specs: Sequence[PdoSpec]) -> None:
        layouts = [pdo_struct(spec) for spec in specs]
        self.sizes = tuple(layout.size for layout in layouts)
        """Bytes each RPDO needs (shorter frames are the caller's to refuse)."""
        self._keys = tuple(spec.keys for spec in specs)
        self._unpack = tuple(layout.unpack_from for layout in layouts)
        self.keys = frozenset(key for keys in self._keys for key in keys)
        """Every object the RPDOs map."""
        if len(self.keys) != sum(len(keys) for keys in self._keys):
            raise ValueError(f"RPDOs {[hex(s.cob_id) for s in specs]} map an object twice")
        self._latest: list[bytes | None] = [None] * len(specs)
        self._order: list[int] = []
        self._applied: list[bytes | None] = [None] * len(specs)

    @property
    def pending(self) -> bool:
        """A frame arrived since the last ``take`` / ``discard``."""
        return bool(self._order)

    def store(self, slot: int, data: bytes) -> None:
        """The latest frame of RPDO ``slot`` (at least ``sizes[slot]`` bytes)."""
        if self._latest[slot] is None:
            self._order.append(slot)
        self._latest[slot] = data

    def discard(self) -> None:
        """Forget the frames received since the last SYNC."""
        for slot in self._order:
            self._latest[slot] = None
        self._order.clear()

    def forget_applied(self) -> None:
        """The RPDO-mapped values were changed or removed by someone else (a reset): the next
        frame of every RPDO is compared value by value again."""
        self._applied = [None] * len(self._applied)

    def take(self, values: dict[Key, int]) -> dict[Key, int]:
        """Merge the frames received since the last SYNC into ``values`` (raw integers by
        object) and return the entries that changed, in the order their RPDOs first arrived,
        each RPDO's objects in frame order."""
        changed: dict[Key, int] = {}
        latest, applied = self._latest, self._applied
        for slot in self._order:
            data, latest[slot] = latest[slot], None
            if data == applied[slot]:
                continue
            applied[slot] = data
            received = tuple(zip(self._keys[slot], self._unpack[slot](data)))
            for key, value in received:
                if values.get(key) != value:
                    changed[key] = value
            values.update(received)
        self._order.clear()
        return changed
