"""Fixtures of the agent's tests: the reference bench (static CiA 301 nodes from the EDS files)
on every available CAN backend, and an ``AgentBus`` connected to it."""
from __future__ import annotations

import pytest

from ersac_hil.agent.bus import AgentBus
from helpers.can_nodes import ReferenceBench
from protocol.can.bench import BENCH


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
