"""The node fixture of the conformance suite.

A *bench kind* starts the node side of a bench on a bus and returns an object with
``devices`` (the ``protocol.can.bench.Device`` entries it serves), ``network`` and ``close()``.
``reference``: minimal nodes built from the EDS files (``helpers.can_nodes.ReferenceBench``);
``simulator``: the firmware simulator's bench. The same tests run against both unchanged.
"""
from __future__ import annotations

import pytest

from firmware_sim.nodes.simbench import SimulatedBench
from helpers.can_nodes import Master, ReferenceBench

BENCH_KINDS = {"reference": ReferenceBench, "simulator": SimulatedBench}


@pytest.fixture(params=sorted(BENCH_KINDS))
def bench(request, can_backend):
    started = BENCH_KINDS[request.param](can_backend)
    yield started
    started.close()


@pytest.fixture
def master(bench, can_backend):
    m = Master(can_backend, bench.devices)
    yield m
    m.close()
