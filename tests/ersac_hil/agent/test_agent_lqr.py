"""LQR balance: the analytic pendulum model against MuJoCo's linearisation, and the closed loop
on the real simulator (no CAN here: tests/ersac_hil/agent/test_agent_episode.py runs it over the bus)."""
from __future__ import annotations

import numpy as np
import pytest

from ersac_hil.agent.lqr import BalanceController, BalanceDesign, PendulumModel
from ersac_hil.agent.robot import UBOT
from ersac_hil.agent.telemetry import Telemetry
from firmware_sim.plant.linearize import balance_model
from firmware_sim.plant.physics import AXES
from firmware_sim.scenarios.base import Scenario
from firmware_sim.simulator import Simulator

DT = 0.005
IDLE_POSE = (Scenario.pose["shoulder_left"], Scenario.pose["elbow_left"])


@pytest.fixture(scope="module")
def idle_sim():
    sim = Simulator(control_period=DT, substeps=5)
    sim.reset("idle", seed=0)
    return sim


def design(pose=IDLE_POSE, payload=0.0):
    return BalanceDesign.compute(PendulumModel.from_robot(UBOT, pose, pose, payload), DT)


def test_pendulum_model_matches_mujoco_linearisation(idle_sim):
    ours = PendulumModel.from_robot(UBOT, IDLE_POSE, IDLE_POSE)
    ac, bc = ours.continuous()
    mj_a, mj_b = balance_model(idle_sim.physics, DT).continuous()
    # gravity couplings (alpha -> phi'', alpha -> alpha'') and torque gains within 10 %
    for i in (2, 3):
        assert ac[i, 1] == pytest.approx(mj_a[i, 1], rel=0.1)
        assert bc[i, 0] == pytest.approx(mj_b[i, 0], rel=0.1)
    # both models: one unstable pole (the pendulum), at the same rate within 10 %
    assert max(np.linalg.eigvals(ac).real) == pytest.approx(max(np.linalg.eigvals(mj_a).real), rel=0.1)


def test_gain_stabilises_mujocos_own_linear_model(idle_sim):
    d = design()
    mj = balance_model(idle_sim.physics, DT)
    assert np.all(np.abs(d.closed_loop_poles) < 1.0)
    assert np.all(np.abs(np.linalg.eigvals(mj.A - mj.B @ d.k)) < 1.0)
    assert d.k[0, 1] < 0  # leaning forward -> drive forward


def telemetry(sim, cycle):
    ax = [sim.axis(a) for a in AXES]
    imu = sim.imu()
    return Telemetry(cycle, tuple(a.position for a in ax), tuple(a.velocity for a in ax),
                     tuple(a.current for a in ax), tuple(a.voltage for a in ax),
                     imu.pitch, imu.pitch_rate, imu.pitch_acc, imu.acc_x, imu.acc_z, (1,) * 5)


def test_stays_upright_for_ten_seconds_without_arm_motion():
    sim = Simulator(control_period=DT, substeps=5)
    sim.reset("idle", seed=1)
    ctl = BalanceController(design())
    tel = telemetry(sim, 0)
    ctl.start(tel)
    errors, x0 = [], sim.truth.base_x
    for k in range(int(10.0 / DT)):
        sim.set_wheel_torque(*ctl.torque(tel))
        sim.step()
        tel = telemetry(sim, k + 1)
        errors.append(tel.pitch - ctl.reference_pitch(tel))
    assert not sim.status.fallen and not ctl.fallen
    assert np.max(np.abs(errors)) < 0.05
    assert abs(sim.truth.base_x - x0) < 0.05
    assert ctl.saturated_cycles == 0


def test_controller_saturates_and_releases_the_wheels_after_a_fall():
    ctl = BalanceController(design())
    pose = (0.0,) * 3 + IDLE_POSE * 2
    upright = UBOT.balance_pitch(IDLE_POSE, IDLE_POSE)
    tel = lambda pitch, rate=0.0: Telemetry(1, pose, (0.0,) * 7, (0.0,) * 7, (0.0,) * 7,
                                            pitch, rate, 0.0, 0.0, 0.0, (1,) * 5)
    ctl.start(tel(upright))
    assert ctl.torque(tel(upright)) == pytest.approx((0.0, 0.0), abs=1e-9)
    left, right = ctl.torque(tel(upright + 0.02))
    assert left == right > 0  # lean forward: roll forward under the body
    assert ctl.torque(tel(upright + 0.2, 2.0))[0] == pytest.approx(UBOT.wheel_torque_limit)
    assert ctl.saturated_cycles == 1
    assert ctl.torque(tel(upright + 0.3)) == (0.0, 0.0) and ctl.fallen and ctl.released == "fallen"
    assert ctl.torque(tel(upright)) == (0.0, 0.0)  # stays released


def test_bracing_controller_releases_the_wheels_at_the_strike():
    ctl = BalanceController(design(), strike_acc=30.0)
    pose = (0.0,) * 3 + IDLE_POSE * 2
    upright = UBOT.balance_pitch(IDLE_POSE, IDLE_POSE)
    tel = lambda acc, cycle: Telemetry(cycle, pose, (0.0,) * 7, (0.0,) * 7, (0.0,) * 7,
                                       upright + 0.01, 0.0, acc, 0.0, 0.0, (1,) * 5)
    ctl.start(tel(0.0, 1))
    assert ctl.torque(tel(5.0, 2))[0] > 0  # balancing noise is not a strike
    assert ctl.torque(tel(-400.0, 3)) == (0.0, 0.0)
    assert ctl.released == "strike" and ctl.released_cycle == 3 and not ctl.fallen
    assert ctl.torque(tel(0.0, 4)) == (0.0, 0.0)
