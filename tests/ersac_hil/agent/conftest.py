"""Fixtures of the agent's tests: the reference bench (static CiA 301 nodes from the EDS files)
on every available CAN backend, and an ``AgentBus`` connected to it."""
from __future__ import annotations

import pytest

from ersac_hil.agent.bus import AgentBus
from firmware_sim.nodes import SlaveNode
from protocol.can.bench import BENCH
from protocol.can.busconfig import open_network


class ReferenceBench:
    """Every bench device as a ``SlaveNode`` with the static application, on its own network."""

    def __init__(self, bus_config, devices=BENCH):
        self.network = open_network(bus_config)
        self.nodes = {d.name: SlaveNode(d) for d in devices}
        for node in self.nodes.values():
            node.connect(self.network)

    def remove(self, name: str) -> None:
        """Take one node off the bus (it stops answering, sending TPDOs and heartbeats)."""
        self.nodes.pop(name).close()

    def close(self):
        for node in self.nodes.values():
            node.close()
        self.network.disconnect()


@pytest.fixture
def make_reference_bench():
    """Factory for benches on buses a test manages itself; closes them at the end."""
    made = []

    def make(bus_config, devices=BENCH):
        made.append(ReferenceBench(bus_config, devices))
        return made[-1]

    yield make
    for bench in made:
        try:
            bench.close()
        except Exception:
            pass


@pytest.fixture
def reference_bench(can_backend):
    bench = ReferenceBench(can_backend)
    yield bench
    bench.close()


@pytest.fixture
def agent_bus(reference_bench, can_backend):
    with AgentBus(can_backend) as bus:
        bus.wait_for_nodes()
        yield bus
