"""The simulator's nodes against the EDS scaling: what the firmware runs after an SDO download
of ``x`` SI units (encoded by canopen with the EDS ``Factor``), and what every telemetry and
ground-truth object reads as (decoded the same way), is the simulator's own SI state."""
from __future__ import annotations

import uuid

import pytest

from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import Master
from protocol.can.devices import ARM_LEFT, DEVICES, IMU, TESTBENCH, TORSO, WHEELS
from protocol.can.busconfig import BusConfig
from protocol.can.objects import OBJECTS, Index

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def rig():
    """A simulated robot half a second into a bracing episode (impact released, torso turning),
    and the test's SDO client with the EDS object dictionaries."""
    config = BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(config)
    master = Master(config, DEVICES)
    with robot.lock:
        robot.sim.reset("bracing", 5)
        robot.sim.trigger_impact()
        robot.sim.controller(TORSO.name).set_setpoint(TORSO.joints[0], 0.3)  # the torso moves too
        for _ in range(100):
            robot.sim.step()
    yield robot, master.nodes
    master.close()
    robot.close()


def _within_a_count(read: float, truth: float, index: int) -> None:
    assert read == pytest.approx(truth, abs=OBJECTS[index].factor / 2 + 1e-9), hex(index)


@pytest.mark.parametrize("device", [WHEELS, TORSO, ARM_LEFT], ids=lambda d: d.name)
def test_axis_telemetry_reads_as_the_simulated_state(rig, device):
    robot, nodes = rig
    sdo = nodes[device.name].sdo
    counts = []
    for sub, joint in enumerate(device.joints, start=1):
        axis = robot.sim.axis(joint)
        for index, truth in ((Index.POSITION, axis.position), (Index.VELOCITY, axis.velocity),
                             (Index.CURRENT, axis.current), (Index.VOLTAGE, axis.voltage)):
            _within_a_count(sdo[index][sub].phys, truth, index)
            counts.append(abs(sdo[index][sub].raw))
    assert max(counts) > 100, "a state of all zeros would not tell scales apart"


def test_imu_reads_as_the_simulated_imu(rig):
    robot, nodes = rig
    sdo, imu = nodes[IMU.name].sdo, robot.sim.imu()
    for index, truth in ((Index.PITCH, imu.pitch), (Index.PITCH_RATE, imu.pitch_rate),
                         (Index.PITCH_ACCELERATION, imu.pitch_acc), (Index.ACCELERATION_X, imu.acc_x),
                         (Index.ACCELERATION_Z, imu.acc_z)):
        _within_a_count(sdo[index].phys, truth, index)


def test_ground_truth_reads_as_the_simulator_truth(rig):
    robot, nodes = rig
    sdo, truth = nodes[TESTBENCH.name].sdo, robot.sim.truth
    assert truth.impact_momentum > 1.0 and truth.sim_time > 0.1
    _within_a_count(sdo[Index.IMPACT_MOMENTUM].phys, truth.impact_momentum, Index.IMPACT_MOMENTUM)
    _within_a_count(sdo[Index.SIM_TIME].phys, truth.sim_time, Index.SIM_TIME)
    for sub, tension in ((1, truth.cable_tension_left), (2, truth.cable_tension_right)):
        _within_a_count(sdo[Index.CABLE_TENSION][sub].phys, tension, Index.CABLE_TENSION)


def test_configuration_in_si_reaches_the_firmware(rig):
    robot, nodes = rig
    sdo, board = nodes[ARM_LEFT.name].sdo, robot.sim.controller(ARM_LEFT.name)
    shoulder, elbow = ARM_LEFT.joints
    sdo[Index.STIFFNESS][1].phys = 123.45
    sdo[Index.DAMPING][2].phys = 0.789
    sdo[Index.CURRENT_LIMIT][1].phys = 4.321
    assert board.impedance(shoulder)[0] == pytest.approx(123.45)
    assert board.impedance(elbow)[1] == pytest.approx(0.789)
    assert board.current_limit(shoulder) == pytest.approx(4.321)
    assert sdo[Index.STIFFNESS][1].phys == pytest.approx(123.45)  # live read of what the board runs
