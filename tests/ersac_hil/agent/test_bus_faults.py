"""A faulty CAN node on the robot's bus: the agent never crashes, the episode ends as a bus fault
(``BusFault``: status ``fault_simulator``, counter ``bus_faults``, no cost terms), nothing of it
is ever an ok episode. A rogue node (its own bus on the same channel) sends, right after the
robot's TPDOs of one SYNC: PDOs of the wrong length, a second copy of a TPDO, a foreign SYNC,
a flood on a high-priority id, an error frame, an SDO answer nobody asked for; and a hypothesis
fuzzer of such frames. Over the virtual bus (frame by frame through canopen) and CAN over
Zenoh (bursts through the TPDO collector)."""
from __future__ import annotations

import threading

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.episode import EpisodeRunner
from ersac_hil.agent.errors import BusFault, SdoTimeout
from firmware_sim.nodes.simrobot import SimulatedRobot
from protocol.can import cobid
from protocol.can.busconfig import open_network
from protocol.can.devices import DEVICES
from protocol.can.pdo import pdo_maps, pdo_struct
from protocol.zenoh import STATUSES, EpisodeRequest

pytestmark = pytest.mark.timeout(300)
IMU = next(d for d in DEVICES if d.name == "imu")
TPDOS = {p.cob_id: pdo_struct(p).size for d in DEVICES for p in pdo_maps(d)
         if p.direction == "tpdo" and 1 <= p.transmission_type <= 240}
RPDOS = sorted({p.cob_id for d in DEVICES for p in pdo_maps(d) if p.direction == "rpdo"})
IMU_TPDO = min(c for c in TPDOS if c & 0x7F == IMU.node_id)


def _frames(kind: str) -> list[can.Message]:
    size = TPDOS[IMU_TPDO]
    return {
        "wrong_length": [can.Message(arbitration_id=IMU_TPDO, data=bytes(size - 1), is_extended_id=False)],
        "too_long": [can.Message(arbitration_id=IMU_TPDO, data=bytes(min(size + 1, 8)), is_extended_id=False)],
        "twice": [can.Message(arbitration_id=IMU_TPDO, data=bytes([0x55] * size), is_extended_id=False)],
        "foreign_sync": [can.Message(arbitration_id=cobid.SYNC, data=b"", is_extended_id=False)],
        "babbler": [can.Message(arbitration_id=0x001, data=bytes(8), is_extended_id=False)] * 50,
        "error_frame": [can.Message(arbitration_id=0x0, is_error_frame=True, data=bytes(8), is_extended_id=False)],
        "sdo_answer": [can.Message(arbitration_id=cobid.sdo_tx(IMU.node_id), data=bytes([0x43, 0x18, 0x10, 1, 0, 0, 0, 0]),
                                   is_extended_id=False)],
    }[kind]


class Rig:
    def __init__(self, config) -> None:  # noqa: ANN001
        self.robot = SimulatedRobot(config)
        self.bus = AgentBus(config).open()  # the defaults: lock-step
        self.bus.wait_for_nodes(timeout_s=30)
        self.runner = EpisodeRunner(self.bus)
        self.rogue = open_network(config)

    def episode(self, frames: list[can.Message] | None = None, at_s: float = 0.5, seed: int = 3):
        """One bracing episode; ``frames`` sent by the rogue node right after the robot's TPDOs
        of the SYNC that takes the simulation past ``at_s``. Returns the result and whether
        the frames went out."""
        injected = threading.Event()

        def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
            if frames is not None and not injected.is_set() and self.robot.sim.sim_time >= at_s:
                injected.set()
                for msg in frames:
                    self.rogue.bus.send(msg)
        self.robot.network.subscribe(cobid.SYNC, on_sync)  # after the robot's own: its TPDOs are out
        try:
            result = self.runner.run(self.runner.plan(EpisodeRequest("rogue", "bracing", (0.35,), seed)))
        finally:
            self.robot.network.unsubscribe(cobid.SYNC, on_sync)
        return result, injected.is_set()

    def close(self) -> None:
        self.rogue.disconnect()
        self.bus.close()
        self.robot.close()


@pytest.fixture
def rig(can_backend):
    r = Rig(can_backend)
    yield r
    r.close()


def _is_bus_fault(result) -> bool:  # noqa: ANN001
    return (result.status == "fault_simulator" and result.fault_counts.get("bus_faults") == 1
            and result.cost_terms == {} and result.total_cost is None and "SYNC cycle" in result.detail)


@pytest.mark.parametrize("can_backend", ["virtual", "zenoh"], indirect=True)
@pytest.mark.parametrize("kind", ["wrong_length", "too_long", "twice", "foreign_sync", "babbler", "error_frame",
                                  "sdo_answer"])
def test_a_faulty_node_ends_the_episode_as_a_bus_fault(rig, kind):
    calm, _ = rig.episode()
    assert calm.status == "ok", calm.detail  # the same episode without the rogue node
    result, injected = rig.episode(_frames(kind))
    assert injected
    assert _is_bus_fault(result), (result.status, result.detail, result.fault_counts)


ROGUE_IDS = sorted({*TPDOS, cobid.SYNC, 0x000, 0x001, 0x07F, 0x100, *RPDOS, cobid.heartbeat(1),
                    *(cobid.sdo_rx(d.node_id) for d in DEVICES), *(cobid.sdo_tx(d.node_id) for d in DEVICES)})
rogue_frame = st.builds(
    lambda cob_id, data, error: can.Message(arbitration_id=cob_id, data=data, is_error_frame=error,
                                            is_extended_id=False),
    st.sampled_from(ROGUE_IDS), st.binary(max_size=8), st.booleans())


@pytest.fixture(scope="module")
def fuzz_rig():
    import uuid
    from protocol.can.busconfig import BusConfig
    r = Rig(BusConfig("virtual", f"fuzz-{uuid.uuid4().hex[:8]}"))
    yield r
    r.close()


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(rogue_frame, min_size=1, max_size=6), at_s=st.floats(0.02, 1.9))
def test_fuzzed_frames_during_episodes_are_never_ok(fuzz_rig, frames, at_s):
    """Frames a faulty node may send (the robot's TPDO, SYNC, NMT, RPDO and SDO ids and
    high-priority ones, any length, error frames): the agent answers every episode, and
    never with ok."""
    try:
        fuzz_rig.bus.check_bus()  # what an earlier example's frames left behind is not this one's
    except BusFault:
        pass
    result, injected = fuzz_rig.episode(frames, at_s)
    assert result.status in STATUSES
    if injected:  # (an earlier fault may end the episode before at_s: then nothing to say)
        assert result.status != "ok", (result.status, result.detail)


@pytest.mark.parametrize("can_backend", ["virtual"], indirect=True)
def test_an_unsolicited_sdo_answer_leaves_later_transfers_clean(rig):
    """An SDO answer nobody asked for is one bus fault, not a debt: the node's later transfers
    and the episodes after them are clean (the agent once counted answers against requests over
    its lifetime, so after one stray answer every later answer of that node was 'to no request')."""
    result, injected = rig.episode(_frames("sdo_answer"))
    assert injected and _is_bus_fault(result), (result.status, result.detail)
    rig.bus.read(IMU.name, 0x1018, 1)  # a transfer of that node: its vendor id
    calm, _ = rig.episode()
    assert calm.status == "ok", calm.detail


@pytest.mark.parametrize("can_backend", ["virtual"], indirect=True)
def test_a_stray_sdo_answer_after_a_timed_out_transfer_is_a_bus_fault(rig):
    """A transfer the node never answered leaves nothing awaited: one later SDO answer of that
    node (the late answer of the timed-out request, or a stray one) is the bus fault it is, not
    the answer of a request the client gave up on (the agent once kept the timed-out request,
    and canopen's abort after it, as unanswered, so the next stray answer of that node passed
    unnoticed); the node's transfers after it are clean."""
    server = cobid.sdo_rx(IMU.node_id)
    answering = list(rig.robot.network.subscribers[server])
    client = rig.bus.nodes[IMU.name].sdo
    patience, client.RESPONSE_TIMEOUT = client.RESPONSE_TIMEOUT, 0.2
    rig.robot.network.unsubscribe(server)  # the IMU's SDO server deaf for one transfer
    with pytest.raises(SdoTimeout):
        rig.bus.read(IMU.name, 0x1018, 1)
    client.RESPONSE_TIMEOUT = patience
    for callback in answering:
        rig.robot.network.subscribe(server, callback)
    result, injected = rig.episode(_frames("sdo_answer"))
    assert injected and _is_bus_fault(result), (result.status, result.detail)
    assert "an SDO answer from imu to no request" in result.detail
    rig.bus.read(IMU.name, 0x1018, 1)  # answered: a transfer of that node after it is clean
    calm, _ = rig.episode()
    assert calm.status == "ok", calm.detail


@pytest.mark.parametrize("can_backend", ["virtual"], indirect=True)
@pytest.mark.parametrize("answer", [b"", bytes([0x43, 0x18, 0x10])], ids=["empty", "3-bytes"])
def test_an_sdo_answer_shorter_than_a_frame_fails_the_transfer_as_a_bus_fault(rig, answer):
    """A node answering a transfer with a frame shorter than an SDO frame's 8 bytes is a bus
    fault naming it (canopen's client parsed it and crashed with struct.error: the fuzzer's
    episode ended 'internal: unpack_from requires a buffer of at least 1 bytes'); the node's
    transfers and episodes after it are clean."""
    server = cobid.sdo_rx(IMU.node_id)
    answering = list(rig.robot.network.subscribers[server])

    def short_answer(can_id: int, data: bytearray, timestamp: float) -> None:
        rig.rogue.bus.send(can.Message(arbitration_id=cobid.sdo_tx(IMU.node_id), data=answer, is_extended_id=False))
    rig.robot.network.unsubscribe(server)
    rig.robot.network.subscribe(server, short_answer)  # the rogue answers in the IMU's place
    with pytest.raises(BusFault, match=f"an SDO answer from imu of {len(answer)} bytes"):
        rig.bus.read(IMU.name, 0x1018, 1)
    rig.robot.network.unsubscribe(server)
    for callback in answering:
        rig.robot.network.subscribe(server, callback)
    assert rig.bus.read(IMU.name, 0x1018, 1) > 0  # its vendor id: the next transfer is clean
    calm, _ = rig.episode()
    assert calm.status == "ok", calm.detail
