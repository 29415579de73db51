"""The node fixture of the conformance suite.

A *node kind* starts the node side of a bus and returns an object with
``devices`` (the ``protocol.can.devices.Device`` entries it serves), ``network`` and ``close()``.
``reference``: minimal nodes built from the EDS files (``helpers.can_nodes.ReferenceNodes``);
``simulator``: the firmware simulator's robot. The same tests run against both unchanged.
"""
from __future__ import annotations

import pytest

from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import Master, ReferenceNodes

NODE_KINDS = {"reference": ReferenceNodes, "simulator": SimulatedRobot}


@pytest.fixture(params=sorted(NODE_KINDS))
def nodes(request, can_backend):
    started = NODE_KINDS[request.param](can_backend)
    yield started
    started.close()


@pytest.fixture
def master(nodes, can_backend):
    m = Master(can_backend, nodes.devices)
    yield m
    m.close()
