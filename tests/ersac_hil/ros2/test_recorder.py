"""The MCAP episodes' writer (``ersac_hil.ros2.recorder``): its fast path into the chunks writes
the files ``mcap``'s own ``Writer.add_message`` writes, byte for byte."""
from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from ersac_hil.ros2 import messages
from ersac_hil.ros2.recorder import McapEpisodes, _Messages

_frame = st.one_of(
    st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)),  # sent: (COB-ID, data)
    st.tuples(st.integers(0, 2**29 - 1), st.integers(0, 7), st.integers(0, 8), st.binary(max_size=8)))
_step = st.one_of(
    st.tuples(st.just("frames"), st.integers(0, 10**6), st.lists(_frame, max_size=20), st.booleans()),
    st.tuples(st.just("write"), st.sampled_from(sorted(messages.TOPICS)), st.integers(0, 10**6),
              st.binary(max_size=400)),
    st.tuples(st.just("log"), st.integers(0, 10**6), st.text(max_size=40)))


def _record(directory, steps, chunk_size, fast):
    files = McapEpisodes(directory, "/ubot1", "ubot1", chunk_size=chunk_size, fast=fast)
    start = 1_764_600_000_000_000_000
    files.begin("ep", start)
    assert (files._messages is not None) == fast  # the fast path is taken where asked for
    for step in steps:
        if step[0] == "frames":
            files.frames((start + step[1] * 1000) / 1e9, step[2], step[3])
        elif step[0] == "write":
            files.write(step[1], step[3], start + step[2] * 1000)
        else:
            files.log(start + step[1] * 1000, messages.LOG_INFO, step[2])
    assert files.end(dropped=3) == "ep.mcap"
    return (directory / "ep.mcap").read_bytes()


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(_step, max_size=60), chunk_size=st.sampled_from([64, 700, 4096, 1 << 20]))
def test_the_fast_path_writes_the_file_mcap_writes(tmp_path_factory, steps, chunk_size):
    fast = _record(tmp_path_factory.mktemp("fast"), steps, chunk_size, True)
    slow = _record(tmp_path_factory.mktemp("slow"), steps, chunk_size, False)
    assert fast == slow


def test_a_long_episode_reads_back_in_order_across_chunks(tmp_path):
    burst = [(0x181 + i, 0, 8, bytearray([i] * 8)) for i in range(13)]
    files = McapEpisodes(tmp_path, "/ubot1", "ubot1", chunk_size=4096)
    files.begin("ep", 0)
    for cycle in range(300):
        files.frames(1.0 + cycle * 0.005, burst, False)
    files.end()
    with open(tmp_path / "ep.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.chunk_count > 10
        frames = [messages.deserialize(msg.data, messages.CAN_FRAME) for _, _, msg in reader.iter_messages()]
    assert [(fr.id, bytes(fr.data)) for fr in frames] == [(i, bytes(d)) for _ in range(300) for i, _, _, d in burst]


def test_a_writer_whose_state_is_not_mcap_1x_gets_its_own_add_message():
    class Other:  # what a future mcap's Writer might be: no private chunk builder
        def add_message(self, *args):
            pass

    assert _Messages.of(Other()) is None  # type: ignore[arg-type]
