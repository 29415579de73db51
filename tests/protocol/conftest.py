"""The node fixture of the conformance suite.

A *bench kind* starts the node side of a bench on a bus and returns an object with
``devices`` (the ``protocol.can.bench.Device`` entries it serves) and ``close()``.
``reference``: minimal nodes built from the EDS files (``firmware_sim.nodes.SlaveNode`` with
the static application). Further kinds (the firmware simulator) register in BENCH_KINDS and
the same tests run against them unchanged.
"""
from __future__ import annotations

import pytest

from firmware_sim.nodes import SlaveNode
from protocol.can.bench import BENCH, object_dictionary
from protocol.can.busconfig import open_network


class ReferenceBench:
    def __init__(self, bus_config):
        self.devices = BENCH
        self.network = open_network(bus_config)
        self.nodes = [SlaveNode(d) for d in BENCH]
        for node in self.nodes:
            node.connect(self.network)

    def close(self):
        for node in self.nodes:
            node.close()
        self.network.disconnect()


BENCH_KINDS = {"reference": ReferenceBench}

try:  # the simulator's bench, once it exists
    from firmware_sim.nodes.simbench import SimulatedBench  # type: ignore
    BENCH_KINDS["simulator"] = SimulatedBench
except ImportError:
    pass


@pytest.fixture(params=sorted(BENCH_KINDS))
def bench(request, can_backend):
    started = BENCH_KINDS[request.param](can_backend)
    yield started
    started.close()


class Master:
    """The test's side of the bus: a canopen network with a RemoteNode per device."""

    def __init__(self, bus_config, devices):
        self.network = open_network(bus_config)
        self.nodes = {d.name: self.network.add_node(d.node_id, object_dictionary(d)) for d in devices}
        self.devices = {d.name: d for d in devices}

    def close(self):
        self.network.disconnect()


@pytest.fixture
def master(bench, can_backend):
    m = Master(can_backend, bench.devices)
    yield m
    m.close()
