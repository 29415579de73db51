"""The feed's hand-off (``ersac_hil.ros2.feed``) against a real feed process: the SYNC loop's
``pump`` never waits, even on a stopped child whose pipe is full, and whoever hands the items
on (the loop or the feed's thread), every cycle and frame reaches the episode's MCAP file
once, in the order the agent had them."""
from __future__ import annotations

import fcntl
import os
import signal
import termios
import threading
import time
import uuid

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Telemetry
from ersac_hil.ros2.feed import Feed
from ersac_hil.ros2.writer import FeedProcess, FeedSettings
from helpers.timing import PATIENCE_S
from helpers.waiting import wait_until
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(240)


def _telemetry(cycle: int) -> Telemetry:
    """Telemetry that names its cycle in every joint's position (and differs from every other)."""
    values = tuple(cycle + j / 10 for j in range(len(JOINTS)))
    return Telemetry(cycle, values, values, values, values, 0.001 * cycle, 0.0, 0.0, 0.0, 9.81,
                     (0,) * len(STATUS_DEVICES))


def _recorded(path) -> tuple[list[float], list[tuple[int, bytes]]]:  # noqa: ANN001
    """The first joint's positions and the CAN frames of one MCAP file, in log order."""
    positions, frames = [], []
    with open(path, "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic.endswith("/joint_states"):
                positions.append(msg.position[0])
            elif channel.topic.endswith("/can"):
                frames.append((msg.id, bytes(msg.data[:msg.dlc])))
    return positions, frames


def _request(tag: str) -> EpisodeRequest:
    return EpisodeRequest(f"ep-{tag}-{uuid.uuid4().hex[:6]}", "bracing", (0.5,), 5)


def test_the_sync_loop_never_waits_for_a_stopped_feed_process_and_loses_nothing(tmp_path):
    """The child is stopped (SIGSTOP: a feed process starved of CPU, as far as it can be):
    6,000 cycles fill its pipe several times over, yet every ``pump`` returns (a pump that
    waited on the pipe would never return while the child is stopped), and once it runs again
    the file holds every cycle once, in order."""
    process = FeedProcess(FeedSettings("ubot1", "/ubot1", record=str(tmp_path)))
    feed = Feed(process, record=tmp_path).start()
    request, n = _request("stop"), 6000
    feed.begin(request, 0.005)
    wait_until(lambda: feed._in_episode, what="the thread to hand on the begin")

    def loop() -> None:
        for cycle in range(1, n + 1):
            feed.observe(_telemetry(cycle))
            feed.frames(time.time(), [(0x80, b""), (0x200 + cycle % 0x80, cycle.to_bytes(4, "little"))], True)
            feed.pump()

    os.kill(process.pid, signal.SIGSTOP)
    try:
        looping = threading.Thread(target=loop, daemon=True)
        looping.start()
        looping.join(PATIENCE_S * 12)
        assert not looping.is_alive(), "the SYNC loop's pump waited for the stopped feed process"
        queued = bytearray(4)
        fcntl.ioctl(process._proc.stdin, termios.FIONREAD, queued)
        assert int.from_bytes(queued, "little") > (1 << 19)  # the pipe was full: the loop went on regardless
    finally:
        os.kill(process.pid, signal.SIGCONT)
    name = feed.end(None, "stopped")
    feed.stop()
    assert feed.dropped == 0
    positions, frames = _recorded(tmp_path / name)
    assert positions == [float(c) for c in range(1, n + 1)]
    assert frames[1::2] == [(0x200 + c % 0x80, c.to_bytes(4, "little")) for c in range(1, n + 1)]


@pytest.fixture(scope="module")
def mcap_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("handoff")


# one episode: (cycles, where the loop pumps, frames per cycle)
_EPISODES = st.lists(st.tuples(st.integers(0, 60), st.sets(st.integers(0, 60)),
                               st.integers(0, 3)), min_size=1, max_size=4)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(episodes=_EPISODES, wake=st.sets(st.integers(0, 60)))
def test_whoever_hands_on_every_item_arrives_once_in_order(mcap_dir, episodes, wake):
    """Episodes of drawn lengths, the loop pumping at drawn cycles and the feed's thread
    woken at others (its ``POLL_S`` look, made to happen there): each file holds its cycles
    and frames once, in the order they were offered."""
    process = FeedProcess(FeedSettings("ubot1", "/ubot1", record=str(mcap_dir)))
    feed = Feed(process, record=mcap_dir).start()
    written = []
    try:
        for k, (cycles, pumps, per_cycle) in enumerate(episodes):
            request = _request(f"h{k}")
            feed.begin(request, 0.005)
            sent = []
            for cycle in range(1, cycles + 1):
                feed.observe(_telemetry(cycle))
                burst = [(0x180 + i, (cycle * 4 + i).to_bytes(4, "little")) for i in range(per_cycle)]
                if burst:
                    feed.frames(time.time(), burst, False)
                sent += burst
                if cycle in pumps:
                    feed.pump()
                if cycle in wake:
                    feed._wake.set()
            written.append((feed.end(None, "stopped"), cycles, sent))
    finally:
        feed.stop()
    for name, cycles, sent in written:
        positions, frames = _recorded(mcap_dir / name)
        assert positions == [float(c) for c in range(1, cycles + 1)]
        assert frames == sent
