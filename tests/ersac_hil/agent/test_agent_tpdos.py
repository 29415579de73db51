"""The TPDOs of one SYNC: collected on a receive thread, waited for by the cycle
(``ersac_hil.agent.tpdos``). Real threads; waits have deadlines, nothing sleeps to sync."""
from __future__ import annotations

import struct
import threading
import time

from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.tpdos import TpdoCollector
from ersac_hil.canbus.zenoh_bus import NOT_DATA

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
    handlers[0x182](0x182, bytearray(b"\x01"), 0.0)  # shorter than its map: not a TPDO
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == {0x182, 0x281} and dict(frames) == {0x181: FRAMES[0x181]}
    handlers[0x182](0x182, bytearray(FRAMES[0x182]), 0.0)  # late: nobody waits for it
    assert c.take(_burst({0x281: FRAMES[0x281]}), 0.0) == _burst({0x281: FRAMES[0x281]})  # left to others
    c.expect()  # the next cycle starts clean and still waits for all three
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == set(SIZES) and dict(frames) == {}
    c.expect()
    for k, d in FRAMES.items():
        handlers[k](k, bytearray(d), 0.0)
        handlers[k](k, bytearray(d), 0.0)  # a second copy changes nothing
    frames, missing = c.wait(time.perf_counter() + 10.0)
    assert not missing and frames[0x182] == FRAMES[0x182]


def test_a_burst_keeps_the_tpdos_and_leaves_the_rest_in_order():
    c, _ = _collector()
    c.expect()
    other = [(0x701, 0, 1, bytearray(b"\x05")), (0x181, _REMOTE, 4, bytearray()), (0x181, 0, 2, bytearray(b"ab"))]
    burst = [other[0]] + _burst({0x181: FRAMES[0x181] + b"xyz"}) + other[1:] + _burst(FRAMES)
    rest = c.take(burst, 0.0)
    # the remote frame, the short frame and the second copy of 0x181 are not this SYNC's TPDOs
    assert rest == other + _burst({0x181: FRAMES[0x181]})
    frames, missing = c.wait(time.perf_counter() + 10.0)
    assert not missing and dict(frames) == FRAMES  # longer frames: the map's bytes


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
    per-frame handlers keep (canopen gives them data frames only) and leaves the others, in
    order."""
    burst_wise, by_frame = TpdoCollector(SIZES), TpdoCollector(SIZES)
    handlers = {cob_id: by_frame.handler(cob_id) for cob_id in SIZES}
    for sync, bursts in cycles:
        if sync:
            burst_wise.expect()
            by_frame.expect()
        for burst in bursts:
            frames = [(cob_id, flags, len(data), bytearray(data)) for cob_id, flags, data in burst]
            rest = burst_wise.take(list(frames), 0.0)
            it = iter(frames)
            assert all(any(f is g for g in it) for f in rest)  # the same frames, a subsequence
            pending = len(by_frame._pending)
            for cob_id, flags, _, data in frames:
                if not flags & NOT_DATA and cob_id in handlers:
                    handlers[cob_id](cob_id, bytearray(data), 0.0)
            assert len(frames) - len(rest) == pending - len(by_frame._pending)  # as many kept
        got_b, got_f = burst_wise.wait(time.perf_counter()), by_frame.wait(time.perf_counter())
        assert {k: bytes(v) for k, v in got_b[0].items()} == {k: bytes(v) for k, v in got_f[0].items()}
        assert set(got_b[1]) == set(got_f[1])
