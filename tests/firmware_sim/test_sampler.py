"""The robot's one TPDO sampler packs exactly the frames each node would pack from its own
application sample (``DeviceApp.sample`` into the node's values, the path of SDO uploads),
bit for bit, over random episode states, board flags and node states."""
from __future__ import annotations

import uuid

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.controllers.firmware import FLAGS
from firmware_sim.nodes.devices import AxisCounts, telemetry_row
from firmware_sim.nodes.sampler import TpdoSampler
from firmware_sim.nodes.simrobot import SimulatedRobot
from protocol.can.busconfig import BusConfig
from protocol.can.nmt import OPERATIONAL, PRE_OPERATIONAL

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def robot():
    robot = SimulatedRobot(BusConfig("virtual", f"sampler-{uuid.uuid4().hex[:8]}"))
    yield robot
    robot.close()


def _node_by_node(robot: SimulatedRobot) -> list[tuple[int, bytes]]:
    """What every operational node packs itself: its application's sample, then its TPDOs
    from its values (every TPDO is due at every SYNC on this robot)."""
    frames = []
    for node in robot.nodes.values():
        if not node.operational or not node.tpdo_layouts:
            continue
        node.app.sample()
        frames += [(t.cob_id, t.layout.pack(*t.values_of(node.values))) for t in node.tpdo_layouts]
    return frames


@settings(max_examples=25, deadline=None)
@given(scenario=st.sampled_from(["idle", "bracing", "lifting"]), seed=st.integers(0, 2 ** 31),
       periods=st.integers(0, 40), torque=st.floats(-8.0, 8.0),
       flags=st.lists(st.booleans(), min_size=56, max_size=56),
       operational=st.lists(st.booleans(), min_size=6, max_size=6),
       safe=st.lists(st.booleans(), min_size=6, max_size=6))
def test_one_sampler_packs_what_each_node_packs(robot, scenario, seed, periods, torque, flags,
                                                operational, safe):
    with robot.lock:
        robot.sim.reset(scenario, seed)
        robot.sim.set_wheel_torque(torque, -torque)
        for _ in range(periods):
            robot.sim.step()
        fw = robot.sim.controller("wheels")._fw
        for row, name in enumerate(FLAGS):  # the flags are rows of one array, written in place
            getattr(fw, name)[:] = flags[row * 7:(row + 1) * 7]
        for node, up, halted in zip(robot.nodes.values(), operational, safe):
            node.nmt._state = OPERATIONAL if up else PRE_OPERATIONAL
            node.app.operational, node.app.safe = up, halted
        expected = _node_by_node(robot)
        axes = AxisCounts.sample(robot.sim)
        got: list[tuple[int, bytes]] = []
        TpdoSampler(tuple(robot.nodes.values())).pack(telemetry_row(axes, robot.sim.imu()), axes, got)
    assert got == expected
    assert len(got) == sum(len(n.tpdo_layouts) for n in robot.nodes.values() if n.operational)


def test_the_robot_packs_each_node_s_tpdos_at_once(robot):
    # every TPDO of the simulated robot goes out at every SYNC: each node's frames come from one
    # struct (the comparison above checks them against the node's own, frame by frame)
    plans = TpdoSampler(tuple(robot.nodes.values()))._plans
    assert plans and all(plan.whole is not None for plan in plans)
    assert sum(len(plan.cuts) for plan in plans) == sum(len(n.tpdo_layouts) for n in robot.nodes.values())
