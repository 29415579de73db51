"""The node fixture of the conformance suite.

A *node kind* starts the node side of a bus and returns an object with
``devices`` (the ``protocol.can.devices.Device`` entries it serves), ``network`` and ``close()``.
``reference``: minimal nodes built from the EDS files (``helpers.can_nodes.ReferenceNodes``);
``simulator``: the firmware simulator's robot. The same tests run against both unchanged.
A failed test's report shows the SDO frames the master and the nodes received (an answer that
never came: was the request or the answer lost?).
"""
from __future__ import annotations

import pytest

from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import Master, ReferenceNodes, SdoTrace

NODE_KINDS = {"reference": ReferenceNodes, "simulator": SimulatedRobot}


@pytest.fixture(params=sorted(NODE_KINDS))
def nodes(request, can_backend):
    started = NODE_KINDS[request.param](can_backend)
    yield started
    started.close()


@pytest.fixture
def master(nodes, can_backend):
    m = Master(can_backend, nodes.devices)
    m.sdo_trace = SdoTrace(m.network, nodes.network, nodes.devices)
    yield m
    m.sdo_trace.close()
    m.close()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):  # noqa: ANN001, ARG001
    """A failed test's report shows the SDO frames both sides received (``SdoTrace``)."""
    outcome = yield
    report = outcome.get_result()
    master = getattr(item, "funcargs", {}).get("master")
    if report.when == "call" and report.failed and isinstance(master, Master):
        report.sections.append(("SDO frames received by the master and by the nodes", master.sdo_trace.describe()))
