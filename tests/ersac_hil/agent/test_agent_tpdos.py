"""The TPDOs of one SYNC: collected on a receive thread, waited for by the cycle
(``ersac_hil.agent.tpdos``). Real threads; waits have deadlines, nothing sleeps to sync."""
from __future__ import annotations

import struct
import threading
import time

from ersac_hil.agent.tpdos import TpdoCollector

LAYOUTS = {0x181: struct.Struct("<hh"), 0x182: struct.Struct("<i"), 0x281: struct.Struct("<B")}
FRAMES = {0x181: struct.pack("<hh", -3, 7), 0x182: struct.pack("<i", 123456), 0x281: b"\x05"}


def _collector() -> tuple[TpdoCollector, dict]:
    c = TpdoCollector(LAYOUTS)
    return c, {cob_id: c.handler(cob_id) for cob_id in LAYOUTS}


def test_the_last_frame_of_the_set_wakes_the_cycle_from_another_thread():
    c, handlers = _collector()
    for _ in range(3):  # the same collector, cycle after cycle
        c.expect()
        sender = threading.Thread(target=lambda: [handlers[k](k, bytearray(d), 0.0) for k, d in FRAMES.items()])
        sender.start()
        frames, missing = c.wait(time.perf_counter() + 10.0)
        sender.join()
        assert missing == set()
        assert frames == {0x181: (-3, 7), 0x182: (123456,), 0x281: (5,)}


def test_missing_frames_after_the_deadline_and_late_ones_are_ignored():
    c, handlers = _collector()
    c.expect()
    handlers[0x181](0x181, bytearray(FRAMES[0x181]), 0.0)
    handlers[0x182](0x182, bytearray(b"\x01"), 0.0)  # shorter than its map: not a TPDO
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == {0x182, 0x281} and frames == {0x181: (-3, 7)}
    handlers[0x182](0x182, bytearray(FRAMES[0x182]), 0.0)  # late: nobody waits for it
    handlers[0x281](0x281, bytearray(FRAMES[0x281]), 0.0)
    c.expect()  # the next cycle starts clean and still waits for all three
    frames, missing = c.wait(time.perf_counter() + 0.01)
    assert missing == set(LAYOUTS) and frames == {}
    c.expect()
    for k, d in FRAMES.items():
        handlers[k](k, bytearray(d), 0.0)
        handlers[k](k, bytearray(d), 0.0)  # a second copy changes nothing
    frames, missing = c.wait(time.perf_counter() + 10.0)
    assert missing == set() and frames[0x182] == (123456,)


def test_nothing_to_wait_for_without_tpdos():
    assert TpdoCollector({}).wait(time.perf_counter() + 10.0) == ({}, set())
