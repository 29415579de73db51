"""A second SDO server on the robot's bus: answers to requests the agent made, but for another
object than the one asked, or a second answer to one request. Whenever such an answer comes
during an episode (its configuration, its SYNC cycles or its ground-truth readouts at the end),
that episode must end as a fault, never ok, and the next episode without the rogue answer is
ok again (the fault is not carried into it).

The real simulated robot and the agent's bus (``AgentBus``, ``EpisodeRunner``) on a virtual
channel, as tests/ersac_hil/agent/test_bus_faults.py runs them; the rogue answer is sent from a
bus of its own, queued ahead of the test bench's own answer (the rogue's callback runs before
the simulator's SDO server), so which answer the agent sees first is fixed."""
from __future__ import annotations

import uuid

import can
import pytest

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.episode import EpisodeRunner
from firmware_sim.nodes.simrobot import SimulatedRobot
from protocol.can import cobid
from protocol.can.busconfig import BusConfig, open_network
from protocol.can.devices import TESTBENCH
from protocol.can.objects import Index
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(300)
SERVER = cobid.sdo_rx(TESTBENCH.node_id)


class Robot:
    def __init__(self) -> None:
        config = BusConfig("virtual", f"sdo-{uuid.uuid4().hex[:8]}")
        self.robot = SimulatedRobot(config)
        self.bus = AgentBus(config).open()
        self.bus.wait_for_nodes(timeout_s=30)
        self.runner = EpisodeRunner(self.bus)
        self.rogue = open_network(config)
        self.answered: list[bytes] = []

    def episode(self, index: int | None = None, same_object: bool = False,  # noqa: ANN201
                abort: bool = False):
        """One bracing episode; the first SDO request of the test bench for ``index`` (any
        command) also answered by the rogue, before the test bench's own answer: for the next
        object (``index + 1``), or for that object with another value (``same_object``); with
        ``abort``, the answer is an abort (general error) of the next object: what the test bench
        itself sends when a second client's broken request reaches it just before the agent's
        (canopen's server aborts with the multiplexer of its last transfer)."""
        real = list(self.robot.network.subscribers[SERVER])

        def rogue(can_id: int, data: bytearray, timestamp: float) -> None:
            asked = int.from_bytes(data[1:3], "little")
            if index is None or asked != index or self.answered:
                return
            command = {0x40: 0x43, 0x20: 0x60}[data[0] & 0xE0]
            other = asked if same_object else asked + 1
            payload = (0x08000000).to_bytes(4, "little") if abort else bytes([0x5A, 0, 0, 0])
            answer = bytes([0x80 if abort else command, *other.to_bytes(2, "little"), data[3], *payload])
            self.answered.append(answer)
            self.rogue.bus.send(can.Message(arbitration_id=cobid.sdo_tx(TESTBENCH.node_id), data=answer,
                                            is_extended_id=False))
        self.robot.network.unsubscribe(SERVER)
        self.robot.network.subscribe(SERVER, rogue)  # first: its answer is queued before the bench's
        for callback in real:
            self.robot.network.subscribe(SERVER, callback)
        try:
            return self.runner.run(self.runner.plan(EpisodeRequest("rogue", "bracing", (0.35,), 3)))
        finally:
            self.robot.network.unsubscribe(SERVER, rogue)

    def close(self) -> None:
        self.rogue.disconnect()
        self.bus.close()
        self.robot.close()


@pytest.fixture
def robot():
    r = Robot()
    yield r
    r.close()


# the test bench's SDO objects an episode uses: its configuration (scenario), and the ground
# truth read once its cycles are over
PHASES = {"configuration": Index.SCENARIO, "ground truth": Index.GROUND_TRUTH_FLAGS}


@pytest.mark.parametrize("phase, same_object", [
    ("configuration", False), ("configuration", True),
    ("ground truth", False),
    ("ground truth", True),
], ids=["configuration-another object", "configuration-a second answer", "ground truth-another object",
        "ground truth-a second answer"])
def test_a_second_sdo_server_faults_the_episode_it_answers_in_and_no_other(robot, phase, same_object):
    calm = robot.episode()
    assert calm.status == "ok", calm.detail  # the same episode without the rogue server
    hit = robot.episode(PHASES[phase], same_object)
    assert robot.answered, "the rogue never answered"
    assert hit.status.startswith("fault_"), (hit.status, hit.detail)
    assert hit.total_cost is None and hit.cost_terms == {}
    after = robot.episode()
    assert after.status == "ok", (after.status, after.detail)  # nothing of it carried on
    assert after.total_cost == calm.total_cost


@pytest.mark.parametrize("phase", PHASES)
def test_an_abort_of_another_transfer_faults_the_episode_and_is_no_refusal(robot, phase):
    """An abort for an object the agent did not ask is a bus fault, never "the test bench
    refused" (which would end the episode as an error reply and stop the run): seen beside CPU
    hogs, when a rogue frame to the test bench's SDO server came just before the agent's
    configuration request."""
    calm = robot.episode()
    assert calm.status == "ok", calm.detail
    hit = robot.episode(PHASES[phase], abort=True)
    assert robot.answered, "the rogue never answered"
    assert hit.status.startswith("fault_"), (hit.status, hit.detail)
    assert "another transfer" in hit.detail, hit.detail
    assert hit.total_cost is None and hit.cost_terms == {}
    after = robot.episode()
    assert after.status == "ok", (after.status, after.detail)
    assert after.total_cost == calm.total_cost
