"""The agent's SDO configuration against the EDS scaling: the counts ``apply_impedance`` and
``download_spline`` leave in the controllers' object dictionaries mean, by the EDS ``Factor`` of
each object, the SI values the agent was asked to write."""
from __future__ import annotations

import uuid

import numpy as np
import pytest
from canopen.objectdictionary import ODVariable

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.configure import apply_impedance, download_spline
from ersac_hil.agent.layout import default_layout
from ersac_hil.agent.policies import ArmImpedance, Spline
from helpers.timing import PATIENCE_S
from protocol.can.devices import ARM_LEFT, ARM_RIGHT, object_dictionary
from protocol.can.busconfig import BusConfig
from protocol.can.objects import Index, spline_position_index, spline_velocity_index

pytestmark = pytest.mark.timeout(60)

ARMS = (ARM_LEFT, ARM_RIGHT)


@pytest.fixture
def configured(make_reference_nodes):
    """An agent bus and the reference controllers of both arms on a fresh virtual channel."""
    config = BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    nodes = make_reference_nodes(config, ARMS)
    with AgentBus(config, devices=ARMS) as bus:
        bus.wait_for_nodes(ARMS, timeout_s=PATIENCE_S)
        yield bus, nodes


def _phys(node, index: int, sub: int) -> float:
    """What the count stored in ``node`` means by the EDS of the arm controller."""
    obj = object_dictionary(ARM_LEFT)[index]
    var = obj if isinstance(obj, ODVariable) else obj[sub]
    return var.decode_phys(int(node.value(index, sub)))


def test_impedance_registers_hold_the_si_values(configured):
    bus, nodes = configured
    assert bus.layout.arms == ARMS == default_layout().arms  # the default description's arm boards
    apply_impedance(bus, ArmImpedance(stiffness=(123.45, 67.89), damping=(1.234, 0.679)))
    for arm in ARMS:
        node = nodes.nodes[arm.name]
        assert [_phys(node, Index.STIFFNESS, s) for s in (1, 2)] == pytest.approx([123.45, 67.89])
        assert [_phys(node, Index.DAMPING, s) for s in (1, 2)] == pytest.approx([1.234, 0.679])


def test_spline_registers_hold_the_si_values(configured):
    bus, nodes = configured
    spline = Spline(times=np.array([0.0, 0.75, 1.5]),
                    positions=np.array([[0.1, 0.2], [1.2, 1.5], [2.0, 0.4]]),
                    velocities=np.array([[0.0, 0.0], [1.25, -0.5], [0.0, 0.0]]))
    download_spline(bus, ARM_LEFT, spline)
    node = nodes.nodes[ARM_LEFT.name]
    assert int(node.value(Index.SPLINE_KNOT_COUNT)) == 3
    for k in range(1, 4):
        assert _phys(node, Index.SPLINE_KNOT_TIME, k) == pytest.approx(spline.times[k - 1])
        for axis in (1, 2):
            assert _phys(node, spline_position_index(axis), k) == pytest.approx(spline.positions[k - 1, axis - 1])
            assert _phys(node, spline_velocity_index(axis), k) == pytest.approx(spline.velocities[k - 1, axis - 1])
