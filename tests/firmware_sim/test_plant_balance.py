"""Balance: the passive robot falls; an LQR computed here from MuJoCo's finite-difference
linearisation (mjd_transitionFD), running at 200 Hz on IMU pitch/pitch rate and wheel
encoders within the wheel torque limits, keeps it upright for 10 s."""
from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.plant import read_motor_params
from firmware_sim.plant.linearize import balance_model
from firmware_sim.simulator import Simulator

Q = np.diag([0.5, 200.0, 0.5, 5.0])   # wheel angle, pitch, wheel rate, pitch rate
R = 1.0                               # per (N m)^2 of wheel torque


def _state(sim: Simulator, pitch0: float, phi0: float) -> np.ndarray:
    imu, wl, wr = sim.imu(), sim.axis("wheel_left"), sim.axis("wheel_right")
    return np.array([0.5 * (wl.position + wr.position) - phi0, imu.pitch - pitch0,
                     0.5 * (wl.velocity + wr.velocity), imu.pitch_rate])


@pytest.fixture(scope="module")
def gains() -> np.ndarray:
    sim = Simulator()
    sim.reset("idle", 0)
    model = balance_model(sim.physics, sim.control_period)
    k = model.lqr_gain(Q, R)
    print("LQR gain K (u = -K x, x = [phi, theta, phi_dot, theta_dot]):", np.round(k, 3))
    return k


def test_linearisation_has_one_unstable_pitch_mode():
    sim = Simulator()
    sim.reset("idle", 0)
    ac, bc = balance_model(sim.physics, sim.control_period).continuous()
    eig = np.linalg.eigvals(ac)
    unstable = eig[eig.real > 0.5]
    assert len(unstable) == 1 and 3.0 < unstable[0].real < 15.0   # falls with ~1/7 s time constant
    assert bc[2, 0] > 0 > bc[3, 0]   # wheel torque speeds the wheels up and pitches the body back


def test_passive_robot_falls_within_two_seconds(gains):
    sim = Simulator(balance_free=True)
    sim.reset("idle", 0)
    pitch0, phi0 = sim.imu().pitch, sim.axis("wheel_left").position
    for _ in range(400):
        u = float(-(gains @ _state(sim, pitch0, phi0))[0])
        sim.set_wheel_torque(u, u)           # ignored: the wheel drivers are passive
        sim.step()
        assert abs(sim.axis("wheel_left").current) < 1e-9
        if sim.status.fallen:
            break
    assert sim.status.fallen and sim.sim_time <= 2.0


def test_lqr_keeps_the_robot_upright_for_ten_seconds(gains):
    sim = Simulator()
    sim.reset("idle", 1)
    limit = read_motor_params(sim.physics.model)["wheel_left"].torque_limit
    pitch0, phi0 = sim.imu().pitch, sim.axis("wheel_left").position
    worst, peak_u = 0.0, 0.0
    for _ in range(2000):
        u = float(np.clip(-(gains @ _state(sim, pitch0, phi0))[0], -limit, limit))
        peak_u = max(peak_u, abs(u))
        sim.set_wheel_torque(u, u)
        sim.step()
        worst = max(worst, abs(sim.truth.pitch - pitch0))
    assert sim.sim_time == pytest.approx(10.0)
    assert not sim.status.fallen
    assert worst < 0.05
    assert abs(sim.truth.base_x) < 0.2
    assert peak_u < limit
