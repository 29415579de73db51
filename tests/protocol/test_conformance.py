"""CiA 301 conformance of every node of the bench, over every available CAN backend.

Written against the ``bench``/``master`` fixtures only (tests/protocol/conftest.py), so the
same tests run against the reference nodes and the firmware simulator.
"""
from __future__ import annotations

import threading
import time

import pytest
from canopen.sdo import SdoAbortedError

from ersac_hil.canbus.heartbeat import HeartbeatProducer
from protocol.can import cobid
from protocol.can.bench import object_dictionary
from protocol.can.objects import EmcyCode, Index, Status
from protocol.can.pdo import pdo_maps
from protocol.can.sdo import RANGE_ABORTS, AbortCode

pytestmark = pytest.mark.timeout(60)


def wait_state(node, state: str, timeout: float = 1.0) -> str:
    deadline = time.monotonic() + timeout
    seen = None
    while time.monotonic() < deadline:
        try:
            seen = node.nmt.wait_for_heartbeat(timeout=max(0.01, deadline - time.monotonic()))
        except Exception:
            continue
        if seen == state:
            return seen
    return seen


def all_state(master, state: str) -> None:
    master.network.nmt.state = state
    for name, node in master.nodes.items():
        assert wait_state(node, state) == state, f"{name} heartbeat does not report {state}"


def test_nmt_transitions_reported_by_heartbeat(master):
    for state in ("OPERATIONAL", "STOPPED", "PRE-OPERATIONAL", "OPERATIONAL"):
        all_state(master, state)


def test_reset_sends_bootup_then_preoperational(master):
    all_state(master, "OPERATIONAL")
    node = next(iter(master.nodes.values()))
    node.nmt.state = "RESET"
    node.nmt.wait_for_bootup(timeout=1.0)
    assert wait_state(node, "PRE-OPERATIONAL") == "PRE-OPERATIONAL"


def test_identity_object_matches_eds(master):
    for name, node in master.nodes.items():
        od = object_dictionary(master.devices[name])
        for sub in (1, 2, 3, 4):
            assert node.sdo[0x1018][sub].raw == od[0x1018][sub].default, (name, sub)
        assert node.sdo[0x1008].raw == od[0x1008].default


def test_sdo_abort_missing_object_and_subindex(master):
    node = next(iter(master.nodes.values()))
    with pytest.raises(SdoAbortedError) as exc:
        node.sdo.upload(0x5FFF, 0)
    assert exc.value.code == AbortCode.NO_OBJECT
    with pytest.raises(SdoAbortedError) as exc:
        node.sdo.upload(0x1018, 0x09)
    assert exc.value.code == AbortCode.NO_SUBINDEX


def test_sdo_abort_read_only_object_changes_nothing(master):
    for name, node in master.nodes.items():
        before = node.sdo[0x1018][1].raw
        with pytest.raises(SdoAbortedError) as exc:
            node.sdo.download(0x1018, 1, b"\x01\x02\x03\x04")
        assert exc.value.code == AbortCode.READ_ONLY, name
        assert node.sdo[0x1018][1].raw == before


def _limited_writable(od):
    for obj in od.values():
        entries = [obj] if not hasattr(obj, "subindices") else [obj[s] for s in obj.subindices if s]
        for var in entries:
            if var.writable and var.max is not None:
                yield var


def test_sdo_abort_out_of_range_value_changes_nothing(master):
    checked = 0
    for name, node in master.nodes.items():
        od = object_dictionary(master.devices[name])
        for var in _limited_writable(od):
            sdo_var = node.sdo[var.index][var.subindex] if var.subindex or hasattr(
                od[var.index], "subindices") else node.sdo[var.index]
            before = sdo_var.raw
            bits = len(var)
            signed = var.min is not None and var.min < 0
            if var.max < (1 << (bits - 1 if signed else bits)) - 1:
                with pytest.raises(SdoAbortedError) as exc:
                    sdo_var.raw = var.max + 1
                assert exc.value.code in RANGE_ABORTS, (name, hex(var.index))
                assert sdo_var.raw == before, (name, hex(var.index), var.subindex)
                checked += 1
            if var.min is not None and var.min > (-(1 << (bits - 1)) if signed else 0):
                with pytest.raises(SdoAbortedError) as exc:
                    sdo_var.raw = var.min - 1
                assert exc.value.code in RANGE_ABORTS
                checked += 1
    assert checked > 10  # stiffness, damping, limits, spline, scenario ... all refused


def _tpdo_counter(master):
    counts: dict[int, int] = {}
    lock = threading.Lock()

    def on_frame(can_id, data, timestamp):
        with lock:
            counts[can_id] = counts.get(can_id, 0) + 1

    expected = [p.cob_id for d in master.devices.values() for p in pdo_maps(d)
                if p.direction == "tpdo" and p.synchronous]
    for cob in expected:
        master.network.subscribe(cob, on_frame)
    return counts, expected


def test_one_tpdo_per_sync_per_mapped_pdo(master):
    counts, expected = _tpdo_counter(master)
    all_state(master, "OPERATIONAL")
    n_sync = 20
    for i in range(n_sync):
        master.network.send_message(cobid.SYNC, b"")
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and any(counts.get(c, 0) < i + 1 for c in expected):
            time.sleep(0.0005)
    time.sleep(0.05)
    assert {hex(c): counts.get(c, 0) for c in expected} == {hex(c): n_sync for c in expected}


def test_no_tpdo_unless_operational(master):
    counts, expected = _tpdo_counter(master)
    all_state(master, "PRE-OPERATIONAL")
    for _ in range(5):
        master.network.send_message(cobid.SYNC, b"")
    time.sleep(0.1)
    assert not counts


def test_rpdo_takes_effect_at_sync(master):
    all_state(master, "OPERATIONAL")
    sent = {}
    for name, node in master.nodes.items():
        node.rpdo.read(from_od=True)
        for pdo_map in node.rpdo.map.values():
            if not pdo_map.enabled:
                continue
            for k, var in enumerate(pdo_map.map):
                od = var.od
                value = 1234 + k if od.index != Index.CONTROL else int(Status(0))
                var.raw = value
                sent[(name, od.index, od.subindex)] = value
            pdo_map.transmit()
    assert sent
    master.network.send_message(cobid.SYNC, b"")
    time.sleep(0.1)
    for (name, index, sub), value in sent.items():
        sdo = master.nodes[name].sdo
        got = sdo[index][sub].raw if sub else sdo[index].raw
        assert got == value, (name, hex(index), sub)


def test_heartbeat_loss_gives_emcy_and_safe_state(master):
    received: dict[int, list[int]] = {}

    def on_emcy(can_id, data, timestamp):
        received.setdefault(can_id & 0x7F, []).append(int.from_bytes(data[:2], "little"))

    for d in master.devices.values():
        master.network.subscribe(cobid.emcy(d.node_id), on_emcy)
    with HeartbeatProducer(master.network):
        all_state(master, "OPERATIONAL")
        time.sleep(0.3)
        assert not received
    stopped = time.monotonic()
    deadline = stopped + 1.0
    ids = {d.node_id for d in master.devices.values()}
    while time.monotonic() < deadline and set(received) != ids:
        time.sleep(0.005)
    elapsed = time.monotonic() - stopped
    assert set(received) == ids, f"EMCY from {sorted(received)}, expected {sorted(ids)}"
    assert elapsed < 3 * 0.1 + 0.1  # within 3 heartbeat periods of the agent
    assert all(EmcyCode.HEARTBEAT_LOST in codes for codes in received.values())
    for name, node in master.nodes.items():
        assert Status(node.sdo[Index.STATUS].raw) & Status.SAFE_STATE, name
