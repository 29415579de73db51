"""The TPDOs of one SYNC: collected on a receive thread, waited for by the cycle
(``ersac_hil.agent.tpdos``). Real threads; waits have deadlines, nothing sleeps to sync."""
from __future__ import annotations

import struct
import threading
import time

from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.tpdos import TpdoCollector
from protocol.can.fastpath import NOT_DATA

SIZES = {0x181: 4, 0x182: 4, 0x281: 1}
FRAMES = {0x181: struct.pack("<hh", -3, 7), 0x182: struct.pack("<i", 123456), 0x281: b"\x05"}
_EXTENDED, _REMOTE, _ERROR = 1, 2, 4


def _collector() -> tuple[TpdoCollector, dict]:
    c = TpdoCollector(SIZES)
    return c, {cob_id: c.handler(cob_id) for cob_id in SIZES}


def _burst(frames: dict[int, bytes]) -> list:
    return [(cob_id, 0, len(data), bytearray(data)) for cob_id, data in frames.items()]


def test_the_last_frame_of_the_set_wakes_the_cycle_from_another_thread():
    c, handlers = _collector()
    for by_burst in (False, True, False, True):  # the same collector, cycle after cycle, either path
        c.expect()
        if by_burst:
            def send() -> None:
                assert c.take(_burst(FRAMES), 0.0) == []
        else:
            def send() -> None:
                for k, d in FRAMES.items():
                    handlers[k](k, bytearray(d), 0.0)
        sender = threading.Thread(target=send)
        sender.start()
        frames, missing = c.wait(time.perf_counter() + 10.0)
        sender.join()
        assert not missing
        assert {k: bytes(v) for k, v in frames.items()} == FRAMES


def test_missing_frames_after_the_deadline_and_late_ones_are_ignored():
    c, handlers = _collector()
    c.expect()
    handlers[0x181](0x181, bytearray(FRAMES[0x181]), 0.0)
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == {0x182, 0x281} and dict(frames) == {0x181: FRAMES[0x181]}
    handlers[0x182](0x182, bytearray(FRAMES[0x182]), 0.0)  # late: nobody waits for it
    assert c.take(_burst({0x281: FRAMES[0x281]}), 0.0) == _burst({0x281: FRAMES[0x281]})  # left to others
    assert c.fault() is None  # late is not faulty
    c.expect()  # the next cycle starts clean and still waits for all three
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == set(SIZES) and dict(frames) == {}


def test_a_tpdo_of_the_wrong_length_or_twice_in_a_cycle_is_a_fault_not_data():
    c, handlers = _collector()
    for wrong in (b"\x01", FRAMES[0x182] + b"\x00"):  # shorter, longer than its map (CiA 301 length errors)
        c.expect()
        handlers[0x182](0x182, bytearray(wrong), 0.0)
        frames, missing = c.wait(time.perf_counter() + 0.01)
        assert 0x182 in missing and 0x182 not in frames
        assert f"TPDO 0x182 of {len(wrong)} bytes, its map has 4" in c.fault()
        assert c.fault() is None  # taken
    c.expect()
    for k, d in FRAMES.items():
        handlers[k](k, bytearray(d), 0.0)
    frames, missing = c.wait(time.perf_counter() + 10.0)
    assert not missing and c.fault() is None
    handlers[0x182](0x182, bytearray(b"\xff\xff\xff\xff"), 0.0)  # a second copy of this cycle's frame
    assert "TPDO 0x182 twice in one cycle" in c.fault() and frames[0x182] == FRAMES[0x182]


def test_a_burst_keeps_the_tpdos_and_leaves_the_rest_in_order():
    c, _ = _collector()
    c.expect()
    heartbeat = (0x701, 0, 1, bytearray(b"\x05"))
    odd = [(0x181, _REMOTE, 4, bytearray()), (0x181, 0, 2, bytearray(b"ab"))]
    burst = [heartbeat] + _burst({0x181: FRAMES[0x181] + b"xyz"}) + odd + _burst(FRAMES)
    rest = c.take(burst, 0.0)
    # the long, remote and short frames of 0x181 are faults, not this SYNC's TPDOs, and not left
    assert rest == [heartbeat]
    frames, missing = c.wait(time.perf_counter() + 10.0)
    assert not missing and dict(frames) == FRAMES
    assert "TPDO 0x181 of 7 bytes" in c.fault()  # the first fault recorded
    known = TpdoCollector(SIZES, known=frozenset({*SIZES, 0x701}))
    known.expect()
    assert known.take([heartbeat, (0x080, 0, 0, bytearray())], 0.0) == [heartbeat]  # a foreign SYNC
    assert "0x080, which no node of the robot sends" in known.fault()


def test_nothing_to_wait_for_without_tpdos():
    frames, missing = TpdoCollector({}).wait(time.perf_counter() + 10.0)
    assert dict(frames) == {} and not missing


frame = st.tuples(st.sampled_from([0x181, 0x182, 0x281, 0x701, 0x80]),
                  st.sampled_from([0, 0, 0, _EXTENDED, _REMOTE, _ERROR]), st.binary(max_size=8))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.lists(st.lists(frame, max_size=8), max_size=4)), max_size=5))
def test_a_burst_at_once_is_the_same_as_frame_by_frame(cycles):
    """Random bursts (TPDOs, other frames, remote and error frames, short, long and repeated
    frames), cycle after cycle, with and without a new SYNC expected: ``take`` keeps what the
    per-frame handlers keep (canopen gives them data frames only), records a fault where they
    do (or for a remote or error frame, which the bus layer records on the per-frame path) and
    leaves the other data frames, in order."""
    burst_wise, by_frame = TpdoCollector(SIZES), TpdoCollector(SIZES)
    handlers = {cob_id: by_frame.handler(cob_id) for cob_id in SIZES}
    for sync, bursts in cycles:
        if sync:
            burst_wise.expect()
            by_frame.expect()
        not_data = False
        for burst in bursts:
            frames = [(cob_id, flags, len(data), bytearray(data)) for cob_id, flags, data in burst]
            rest = burst_wise.take(list(frames), 0.0)
            it = iter(frames)
            assert all(any(f is g for g in it) for f in rest)  # the same frames, a subsequence
            assert not [f for f in rest if f[1] & NOT_DATA]  # remote and error frames are faults
            assert [f for f in rest if f[0] not in SIZES] == [f for f in frames if f[0] not in SIZES
                                                              and not f[1] & NOT_DATA]  # the others left
            for cob_id, flags, _, data in frames:
                not_data |= bool(flags & NOT_DATA)
                if not flags & NOT_DATA and cob_id in handlers:
                    handlers[cob_id](cob_id, bytearray(data), 0.0)
        got_b, got_f = burst_wise.wait(time.perf_counter()), by_frame.wait(time.perf_counter())
        assert {k: bytes(v) for k, v in got_b[0].items()} == {k: bytes(v) for k, v in got_f[0].items()}
        assert set(got_b[1]) == set(got_f[1])
        fault_b, fault_f = burst_wise.fault(), by_frame.fault()
        assert (fault_b is not None) == (fault_f is not None or not_data)
