"""CiA 301 conformance of every node of the robot, over every available CAN backend.

Written against the ``nodes``/``master`` fixtures only (tests/protocol/conftest.py), so the
same tests run against the reference nodes and the firmware simulator. Every wait is on frames
(or an SDO barrier) with a deadline; how fast the nodes react is measured by bench/fault_latency.py.
"""
from __future__ import annotations

import time

import pytest
from canopen.sdo import SdoAbortedError

from ersac_hil.canbus.heartbeat import HeartbeatProducer
from helpers.can_nodes import FrameLog, heartbeats, reported, sdo_barrier, set_state
from protocol.can import cobid
from protocol.can.devices import AGENT_NODE_ID, object_dictionary
from protocol.can.objects import EmcyCode, Index, Status
from protocol.can.pdo import pdo_maps
from protocol.can.sdo import RANGE_ABORTS, AbortCode

pytestmark = pytest.mark.timeout(60)


def all_state(master, state: str) -> None:
    set_state(master.network, master.devices.values(), state)


def test_nmt_transitions_reported_by_heartbeat(master):
    for state in ("OPERATIONAL", "STOPPED", "PRE-OPERATIONAL", "OPERATIONAL"):
        all_state(master, state)


def test_reset_sends_bootup_then_preoperational(master):
    all_state(master, "OPERATIONAL")
    name, node = next(iter(master.nodes.items()))
    log = heartbeats(master.network, master.devices.values())  # before the reset: boot-up may come at once
    try:
        node.nmt.state = "RESET"
        booted = log.wait_for(reported(node.id, "INITIALISING"), what=f"{name} boot-up")
        log.wait_for(reported(node.id, "PRE-OPERATIONAL", after=booted),
                     what=f"{name} PRE-OPERATIONAL after its boot-up")
    finally:
        log.close()


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


def _tpdo_log(master) -> FrameLog:
    return FrameLog(master.network, [p.cob_id for d in master.devices.values() for p in pdo_maps(d)
                                     if p.direction == "tpdo" and p.synchronous])


def test_one_tpdo_per_sync_per_mapped_pdo(master):
    log = _tpdo_log(master)
    all_state(master, "OPERATIONAL")
    n_sync = 20
    for i in range(1, n_sync + 1):
        master.network.send_message(cobid.SYNC, b"")
        log.wait_for(lambda frames: all(n >= i for n in log.counts().values()), what=f"TPDOs of SYNC {i}")
    sdo_barrier(master.nodes.values())  # anything sent after the last SYNC's TPDOs is in now
    assert log.counts() == {c: n_sync for c in log.cob_ids}


def test_no_tpdo_unless_operational(master):
    log = _tpdo_log(master)
    all_state(master, "PRE-OPERATIONAL")
    for _ in range(5):
        master.network.send_message(cobid.SYNC, b"")
    sdo_barrier(master.nodes.values())  # every node has handled the SYNCs before it answers
    assert not log.frames


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
    # the SDO reads below reach each node after its RPDOs and the SYNC, in bus order
    for (name, index, sub), value in sent.items():
        sdo = master.nodes[name].sdo
        got = sdo[index][sub].raw if sub else sdo[index].raw
        assert got == value, (name, hex(index), sub)


#: How much later than a node's own handler the test's log may note a frame of the same dispatch.
NOTING_SLACK_S = 0.05


def test_heartbeat_loss_gives_emcy_and_safe_state(master, nodes):
    ids = {d.node_id for d in master.devices.values()}
    emcy = FrameLog(master.network, [cobid.emcy(i) for i in ids])
    beats = heartbeats(master.network, master.devices.values())
    # the agent's heartbeat as the nodes receive it: their consumer's clock, not the producer's
    agent = FrameLog(nodes.network, [cobid.heartbeat(AGENT_NODE_ID)])
    consumer_s = max(object_dictionary(d)[0x1016][1].default & 0xFFFF for d in master.devices.values()) / 1000
    producer_s = min(object_dictionary(d)[0x1017].default for d in master.devices.values()) / 1000
    with HeartbeatProducer(master.network):
        all_state(master, "OPERATIONAL")
        # every node beats for longer than its consumer time while the agent's heartbeat runs
        n_beats = int(consumer_s / producer_s) + 2
        beats.wait_for(lambda frames: all(beats.count(cobid.heartbeat(i)) >= n_beats for i in ids),
                       what=f"{n_beats} heartbeats of every node")
        sdo_barrier(master.nodes.values())
        # no EMCY while the agent's heartbeat reached the nodes within their consumer time; a
        # loaded machine can hold a frame (or the producer) for longer, and then the EMCY is right
        silence = agent.longest_silence(cobid.heartbeat(AGENT_NODE_ID), time.monotonic())
        assert not emcy.frames or silence > consumer_s - NOTING_SLACK_S, (
            f"EMCY of nodes {sorted({c & 0x7F for c, _ in emcy.frames})} while the agent's heartbeat never "
            f"stayed away from the nodes for longer "
            f"than {1000 * silence:.0f} ms (consumer time {1000 * consumer_s:.0f} ms)")
    agent.close()
    emcy.wait_for(lambda frames: {c & 0x7F for c, _ in frames} == ids, what="EMCY from every node")
    codes = {}
    for can_id, data in emcy.frames:
        codes.setdefault(can_id & 0x7F, []).append(int.from_bytes(data[:2], "little"))
    assert all(EmcyCode.HEARTBEAT_LOST in c for c in codes.values()), codes
    for name, node in master.nodes.items():
        assert Status(node.sdo[Index.STATUS].raw) & Status.SAFE_STATE, name
