"""The feed process (``ersac_hil.ros2.writer``) on its own: it refuses to start with one line
and leaves no child; it outlasts the SIGTERM that reaches an agent's whole process group and
finishes every file it was sent when its input ends."""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Telemetry
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.ros2.writer import CLOSE_WAIT_S, FeedProcess, FeedProcessError, FeedSettings
from ersac_hil.zenoh_session import ZenohOptions, free_tcp_port
from helpers.timing import PATIENCE_S
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(120)


def _children() -> set[int]:
    pids: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        pids |= {int(p) for p in (task / "children").read_text().split()}
    return pids


def _telemetry(cycle: int) -> Telemetry:
    zeros = (0.0,) * len(JOINTS)
    return Telemetry(cycle, zeros, zeros, zeros, zeros, 0.01 * cycle, 0.0, 0.0, 0.0, 9.81,
                     (0,) * len(STATUS_DEVICES))


def test_a_feed_process_that_cannot_open_its_session_is_refused_and_gone(capfd):
    before = _children()
    settings = FeedSettings("ubot1", "/ubot1", ros2=Ros2Options(),
                            zenoh=ZenohOptions((f"tcp/127.0.0.1:{free_tcp_port()}",)))  # nobody listens
    with pytest.raises(FeedProcessError, match="did not start"):
        FeedProcess(settings, ready_wait_s=PATIENCE_S * 6)
    assert _children() == before
    assert "feed process failed" in capfd.readouterr().err  # the child's own one line


def test_a_group_sigterm_does_not_cut_the_files_short(tmp_path):
    process = FeedProcess(FeedSettings("ubot1", "/ubot1", record=str(tmp_path)))
    request = EpisodeRequest("ep-t1", "bracing", (0.5,), 5)
    process.send([("begin", request, time.time_ns(), 5_000_000)])
    process.send([("cycle", _telemetry(c)) for c in range(1, 201)])
    process.send([("frames", time.time(), [(0x80, b"")], True), ("end", None, "stopped", time.time_ns(), 0)])
    os.kill(process.pid, signal.SIGTERM)  # what a supervisor's SIGTERM of the agent's group does to it
    assert process.close(time.monotonic() + max(CLOSE_WAIT_S, PATIENCE_S * 6)) == 0
    with open(tmp_path / "ep-t1.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts["/ubot1/joint_states"] == counts["/ubot1/imu"] == 200
    assert counts["/ubot1/can"] == 1 and counts["/ubot1/events"] == 2


def test_stop_now_at_any_moment_of_the_end_is_a_clean_exit(tmp_path):
    """The agent's deadline (``STOP_NOW``) may meet a child that has just seen the end of its
    input and is on its way out; the signal is sent again and again from then until the child
    is gone, so it lands in every step of the way out. The child always ends by its own hand
    (exit 0), never by the signal's default action (-SIGUSR1, which the interpreter's
    finalization restored before the child left without it)."""
    for episode in range(3):
        process = FeedProcess(FeedSettings("ubot1", "/ubot1", record=str(tmp_path)))
        request = EpisodeRequest(f"ep-s{episode}", "bracing", (0.5,), 5)
        process.send([("begin", request, time.time_ns(), 5_000_000)])
        process.send([("cycle", _telemetry(c)) for c in range(1, 21)])
        process.send([("end", None, "stopped", time.time_ns(), 0)])
        process._proc.stdin.close()  # the input ends
        while process._proc.poll() is None:
            try:
                os.kill(process.pid, signal.SIGUSR1)
            except ProcessLookupError:
                break
            time.sleep(0.0005)
        assert process._proc.wait() == 0
