"""CAN traces per episode (``agent --record-can``): real agent service, simulated robot on a
virtual bus, real Zenoh router; the traces read back with python-can."""
from __future__ import annotations

import uuid

import can
import pytest

from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.agent.trace import CanRecorder
from ersac_hil.zenoh_session import EmbeddedRouter
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.waiting import wait_until
from protocol.can import cobid
from protocol.can.busconfig import BusConfig, open_bus
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

pytestmark = pytest.mark.timeout(120)


def test_each_episode_writes_a_blf_trace_named_in_the_result(tmp_path):
    bus = BusConfig("virtual", f"trace-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-trace")
    robot = SimulatedRobot(bus)
    try:
        with EmbeddedRouter() as router:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,),
                                 record_can=str(tmp_path / "traces"))
            with AgentService(config), router.open_client() as session:
                wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                replies = []
                for eid in ("ep-a", "ep-b"):
                    request = EpisodeRequest(eid, "bracing", (0.3,), 5)
                    replies += [EpisodeResult.from_json(r.ok.payload)
                                for r in session.get(keys.episode_run, payload=request.to_json(), timeout=60)]
    finally:
        robot.close()
    # (an episode a loaded machine turns into a fault has its trace too: not asserted ok)
    assert [r.trace for r in replies] == ["ep-a.blf", "ep-b.blf"]
    for result in replies:
        frames = list(can.LogReader(str(tmp_path / "traces" / result.trace)))
        ids = [f.arbitration_id for f in frames]
        cycles = round(result.telemetry.get("n_cycles", 1))
        assert ids.count(cobid.SYNC) >= max(cycles, 1)  # every control cycle of the episode
        assert len(set(ids)) > 10  # SYNC, RPDOs, TPDOs, heartbeats of every node


def test_asc_traces_and_frames_between_episodes_are_dropped(tmp_path):
    config = BusConfig("virtual", f"trace-{uuid.uuid4().hex[:8]}")
    sender = open_bus(config)
    recorder = CanRecorder(config, tmp_path, "asc").start()
    try:
        def send(n: int) -> None:
            for i in range(n):
                sender.send(can.Message(arbitration_id=0x181, data=[i, 1, 2]))
        send(5)  # no episode: not recorded
        recorder.begin("e1")
        send(20)
        wait_until(lambda: recorder.frames >= 20)
        assert recorder.end() == "e1.asc" and recorder.end() == ""
    finally:
        recorder.stop()
        sender.shutdown()
    frames = list(can.LogReader(str(tmp_path / "e1.asc")))
    assert [f.data[0] for f in frames] == list(range(20))
    with pytest.raises(ValueError, match="format"):
        CanRecorder(config, tmp_path, "mf4")


@pytest.mark.parametrize("fmt", ["blf", "asc"])
def test_a_channel_name_ending_in_a_large_number_is_recorded(tmp_path, fmt):
    """python-can's writers take a channel's trailing digits as its number (BLF: 16 bits): a
    virtual channel such as ``trace-1a970355`` (or a Zenoh one ending in a port) must not stop
    the tap."""
    config = BusConfig("virtual", f"trace-{uuid.uuid4().hex[:3]}99999")
    sender = open_bus(config)
    recorder = CanRecorder(config, tmp_path, fmt).start()
    try:
        recorder.begin("e1")
        for i in range(3):
            sender.send(can.Message(arbitration_id=0x181, data=[i]))
        wait_until(lambda: recorder.frames >= 3, what="three frames in the trace")
        assert recorder.end() == f"e1.{fmt}"
    finally:
        recorder.stop()
        sender.shutdown()
    assert [f.data[0] for f in can.LogReader(str(tmp_path / f"e1.{fmt}"))] == [0, 1, 2]
