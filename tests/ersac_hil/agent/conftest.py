"""Fixtures of the agent's tests: the reference nodes (static CiA 301 nodes from the EDS files)
on every available CAN backend, and an ``AgentBus`` connected to it."""
from __future__ import annotations

import pytest

from ersac_hil.agent.bus import AgentBus
from helpers.can_nodes import ReferenceNodes
from helpers.timing import PATIENCE_S, PATIENT_CONSUMER
from protocol.can.devices import DEVICES
from protocol.can.objects import Index


@pytest.fixture
def make_reference_nodes():
    """Factory for benches on buses a test manages itself; closes them at the end."""
    made = []

    def make(bus_config, devices=DEVICES):
        made.append(ReferenceNodes(bus_config, devices))
        return made[-1]

    yield make
    for nodes in made:
        try:
            nodes.close()
        except Exception:
            pass


@pytest.fixture
def reference_nodes(can_backend):
    nodes = ReferenceNodes(can_backend)
    for node in nodes.nodes.values():  # a stalled agent heartbeat is not what these tests test
        node.set_value(Index.CONSUMER_HEARTBEAT, 1, PATIENT_CONSUMER)
    yield nodes
    nodes.close()


@pytest.fixture
def agent_bus(reference_nodes, can_backend):
    with AgentBus(can_backend) as bus:
        bus.wait_for_nodes(timeout_s=PATIENCE_S)
        yield bus
