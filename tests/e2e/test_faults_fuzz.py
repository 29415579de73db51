"""A hypothesis fuzzer of CAN frames during episodes, end to end: a rogue node on the robot's
real CAN-over-Zenoh channel (its own bus on the simulator's listener) sends drawn frames (any
11-bit id, the robot's own ids more often; any length and payload; error frames) while the real
agent runs a lock-step bracing episode against the real simulator (router, simulator and agent
as separate processes, ``ersac_hil.stack.faults.Rig``; the episode asked over Zenoh as the daemon asks
it). Every episode must come back with the agent alive and be either a fault (a bus fault for
what no node sends; a frame on a node's own EMCY or heartbeat id may read as that node's) or ok
and bit for bit the episode of the same request without the node: never ok with another result.

NMT commands (COB-ID 0x000) are left to the agent-level fuzzer (tests/ersac_hil/agent/
test_bus_faults.py): a reset leaves the simulated nodes down for good, after which no episode
of this module could be ok any more.
"""
from __future__ import annotations

import itertools
import time

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.daemon.replies import decode_reply
from ersac_hil.zenoh_session import make_config, open_session
from ersac_hil.stack.faults import ROBOT, Rig, robot_cob_ids
from helpers.processes import gone
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

pytestmark = pytest.mark.slow

SEED, THETA = 3, (0.35,)
EPISODE_S = 120.0
"""How long one episode may take at most (bounds a hang; no statement of speed)."""


class Robot:
    """Router, simulator and agent (no daemon); episodes asked over a client session."""

    def __init__(self, work) -> None:  # noqa: ANN001
        self.rig = Rig(work, SEED, 0)
        try:
            self.rig.start_router()
            self.rig.start_robot()
            self.session = open_session(make_config(connect=[self.rig.endpoint]))
            self.rogue = can.Bus(interface="zenoh", channel=self.rig.can_channel)
        except BaseException:
            self.rig.close()
            raise
        self.keys = KeySpace(ROBOT)
        self._ids = (f"fuzz.{n:05d}.0" for n in itertools.count())

    def episode(self, frames: list[can.Message] = (), after_s: float = 0.0) -> EpisodeResult:
        """One episode of ``(THETA, SEED)``; ``frames`` sent by the rogue node ``after_s``
        seconds after the request went out."""
        request = EpisodeRequest(next(self._ids), "bracing", THETA, SEED)
        replies = self.session.get(self.keys.episode_run, payload=request.to_json(), timeout=EPISODE_S)
        if frames:
            time.sleep(after_s)  # when the node strikes, not a synchronisation
            for msg in frames:
                self.rogue.send(msg)
        reply = next(iter(replies))
        result = decode_reply(reply, EpisodeResult)
        assert result.episode_id == request.episode_id
        return result

    def close(self) -> None:
        self.rogue.shutdown()
        self.session.close()
        self.rig.close()


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    made = Robot(tmp_path_factory.mktemp("fuzz"))
    try:
        clean = made.episode()
        assert clean.status == "ok", clean.detail  # the episode without the rogue node
        yield made, clean
    finally:
        made.close()
    assert all(gone(pid) for pid in made.rig.pids)


def _message(cob_id: int, data: bytes, error: bool) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_error_frame=error, is_extended_id=False)


IDS = sorted(robot_cob_ids() - {0x000})
rogue_frame = st.builds(_message, st.one_of(st.sampled_from(IDS), st.integers(0x001, 0x7FF)),
                        st.binary(max_size=8), st.sampled_from([False, False, False, True]))


def _learned(result: EpisodeResult) -> tuple:
    """What of an episode the learner uses or stores as its outcome."""
    return (result.status, result.cost_terms, result.total_cost, result.failures, result.duration_s)


CALM_AFTER = 3
"""Episodes after a faulted one by which the bus must be calm again (frames of the burst still in
flight when the hit episode ended fault the next one, as they should)."""


def _judged(robot_: Robot, clean: EpisodeResult, result: EpisodeResult, frames: list[can.Message]) -> None:
    assert robot_.rig.children["agent"].alive(), "the agent crashed"
    if result.status == "ok":  # the node's frames changed nothing the agent heard: the same episode
        assert _learned(result) == _learned(clean), (frames, result.detail)
    else:
        assert result.status.startswith("fault_") and result.total_cost is None, (result.status, result.detail)


@settings(max_examples=10, deadline=None, database=None)
@given(frames=st.lists(rogue_frame, min_size=1, max_size=6), at=st.floats(0.0, 0.9))
def test_fuzzed_frames_during_episodes_are_faults_or_the_clean_episode(robot, frames, at):
    """``frames`` sent at ``at`` of the clean episode's wall time into the episode; then
    episodes without the node until one is ok (each judged the same way), so every example
    starts on a calm bus."""
    robot_, clean = robot
    result = robot_.episode(frames, at * clean.wall_s)
    _judged(robot_, clean, result, frames)
    for _ in range(CALM_AFTER):
        if result.status == "ok":
            break
        result = robot_.episode()
        _judged(robot_, clean, result, frames)
    assert result.status == "ok", f"no ok episode within {CALM_AFTER} after the node went: {result.detail}"
