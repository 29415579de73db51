"""A node's RPDO inbox gives, SYNC after SYNC, exactly what the merge of every received value
by object gives (the nodes' former dict of pending values): the same changed values in the same
order, the same application values, over random frames, repeats, resets and values set by hand."""
from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.nodes.inbox import RpdoInbox
from protocol.can.devices import device
from protocol.can.pdo import pdo_maps, pdo_struct

_ARM = next(p for p in pdo_maps(device("arm_left")) if p.direction == "rpdo")
SPECS = (  # the arm's RPDO split in two: one node, two RPDOs mapping distinct objects
    dataclasses.replace(_ARM, entries=_ARM.entries[:2]),
    dataclasses.replace(_ARM, number=2, cob_id=_ARM.cob_id + 0x100, entries=_ARM.entries[2:]),
)
LAYOUTS = [pdo_struct(spec) for spec in SPECS]


class _Reference:
    """The former formulation: every frame unpacked into a dict of pending values at once;
    at SYNC the changed entries and an update of the values."""

    def __init__(self) -> None:
        self.pending: dict = {}

    def store(self, slot: int, data: bytes) -> None:
        self.pending.update(zip(SPECS[slot].keys, LAYOUTS[slot].unpack_from(data)))

    def take(self, values: dict) -> dict:
        changed = {k: v for k, v in self.pending.items() if values.get(k) != v}
        values.update(self.pending)
        self.pending = {}
        return changed


def _frame(slot: int, pool: int) -> bytes:
    """One of a few frames per RPDO (so that repeats are common)."""
    values = [(pool * 7 + k * 3) % 5 for k in range(len(SPECS[slot].entries))]
    return LAYOUTS[slot].pack(*values)


_OPS = st.lists(st.one_of(
    st.tuples(st.just("frame"), st.integers(0, 1), st.integers(0, 3)),
    st.tuples(st.just("sync")),
    st.tuples(st.just("reset")),
    st.tuples(st.just("set"), st.integers(0, len(_ARM.keys) - 1), st.integers(0, 4)),
), max_size=60)


@settings(max_examples=300)
@given(_OPS)
def test_the_inbox_merges_like_a_dict_of_pending_values(ops):
    inbox, reference = RpdoInbox(SPECS), _Reference()
    values: dict = {}
    expected: dict = {}
    for op in ops:
        if op[0] == "frame":
            data = _frame(op[1], op[2])
            inbox.store(op[1], data)
            reference.store(op[1], data)
        elif op[0] == "sync":
            assert inbox.pending == bool(reference.pending)
            got = inbox.take(values)
            want = reference.take(expected)
            assert list(got.items()) == list(want.items())
            assert values == expected
        elif op[0] == "reset":  # SlaveNode.reset_application: pending dropped, RPDO values removed
            inbox.discard()
            inbox.forget_applied()
            reference.pending = {}
            for key in _ARM.keys:
                values.pop(key, None)
                expected.pop(key, None)
        else:  # SlaveNode.set_value on an RPDO-mapped object
            key = _ARM.keys[op[1]]
            values[key] = expected[key] = op[2]
            inbox.forget_applied()


def test_an_object_mapped_twice_is_refused():
    with pytest.raises(ValueError, match="twice"):
        RpdoInbox((SPECS[0], dataclasses.replace(SPECS[1], entries=_ARM.entries[1:])))
