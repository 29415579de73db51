"""The simulator's nodes against the EDS scaling: what the firmware runs after an SDO download
of ``x`` SI units (encoded by canopen with the EDS ``Factor``), and what every telemetry and
ground-truth object reads as (decoded the same way), is the simulator's own SI state."""
from __future__ import annotations

import uuid
from dataclasses import astuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.controllers import BOARDS
from firmware_sim.controllers.firmware import FLAGS
from firmware_sim.nodes.devices import _AXIS_SCALES, _STATUS_BITS, AxisCounts, axis_counts
from firmware_sim.nodes.simrobot import SimulatedRobot
from firmware_sim.plant import AXES
from firmware_sim.simulator import Simulator
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


_ROW_SCALES = tuple(tuple(s for s in row) for row in _AXIS_SCALES)
_SI = st.one_of(st.floats(-1e300, 1e300), st.sampled_from([np.inf, -np.inf]),   # saturation
                st.integers(-(2 ** 33), 2 ** 33).map(lambda k: k * 0.5e-4),   # near and at half counts
                st.floats(-10.0, 10.0))


@settings(max_examples=300)
@given(st.lists(_SI, min_size=28, max_size=28))
def test_axis_counts_are_scale_to_raw_bit_for_bit(values):
    # every axis at once (numpy) must give exactly what Scale.to_raw gives value by value
    grid = np.array(values).reshape(4, 7)
    expected = [scale.to_raw(float(v)) for scales, row in zip(_ROW_SCALES, grid)
                for scale, v in zip(scales, row)]
    assert axis_counts(grid.ravel().tolist()) == expected


def test_axis_counts_refuse_nan_like_to_raw():
    grid = np.zeros((4, 7))
    grid[2, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        axis_counts(grid.ravel().tolist())


@settings(max_examples=100)
@given(st.lists(st.booleans(), min_size=56, max_size=56))
def test_axis_status_words_or_to_each_boards_status(flags):
    # the per-axis words OR-ed over a board's axes are its board_status() bits as status word
    sim = Simulator()
    sim.reset("idle", 0)
    fw = sim.controller("wheels")._fw  # the flags are rows of fw.flags(), written in place
    for row, name in enumerate(FLAGS):
        getattr(fw, name)[:] = flags[row * 7:(row + 1) * 7]
    words = AxisCounts.sample(sim).words
    for board, axes in BOARDS.items():
        status = sim.controller(board).board_status()
        expected = 0
        for bit, value in zip(_STATUS_BITS, astuple(status)):
            expected |= int(bit) if value else 0
        got = 0
        for axis in axes:
            got |= words[AXES.index(axis)]
        assert got == expected, board
