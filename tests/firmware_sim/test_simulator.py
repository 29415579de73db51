"""The Simulator facade: determinism, resets that restore everything, events reported once,
API errors."""
from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.controllers import ConfigStateError, UnknownAxisError
from firmware_sim.plant import AXES
from firmware_sim.scenarios import UnknownScenarioError
from firmware_sim.simulator import FailureKind, Simulator

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")


def telemetry(sim: Simulator, scenario: str, seed: int, steps: int = 120,
              stiffness: float = 120.0) -> np.ndarray:
    """Reset, then a fixed command sequence (impedance, wheel torques from the IMU, a spline,
    setpoints); returns every step's telemetry, shape (steps, 7 * 4 + 5 + 3)."""
    sim.reset(scenario, seed)
    for axis in ARM:
        sim.set_impedance(axis, stiffness, 2.0)
    q = sim.axis("shoulder_left").position
    sim.load_spline("shoulder_left", [0.0, 0.3], [q, q + 0.3], [0.0, 0.0])
    rows = []
    for k in range(steps):
        imu = sim.imu()
        u = 40.0 * imu.pitch + 8.0 * imu.pitch_rate
        sim.set_wheel_torque(u, u)
        if k == 10:
            sim.start_spline("shoulder_left")
        if k == 30:
            sim.set_setpoint("elbow_right", sim.axis("elbow_right").position + 0.2)
        sim.step()
        axes = [v for a in sim.axes().values() for v in (a.position, a.velocity, a.current, a.voltage)]
        t = sim.truth
        rows.append(axes + list(vars(sim.imu()).values())
                    + [t.cable_tension_left, t.cable_tension_right, t.sim_time])
    return np.array(rows)


@pytest.mark.parametrize("scenario", ["idle", "bracing", "lifting"])
def test_same_seed_same_commands_bit_identical(scenario):
    a = telemetry(Simulator(), scenario, 11)
    b = telemetry(Simulator(), scenario, 11)
    assert a.tobytes() == b.tobytes()
    c = telemetry(Simulator(), scenario, 12, steps=20)
    assert not np.array_equal(a[:20], c)          # other IMU noise (and impact momentum)


def test_reset_restores_everything_an_episode_changed():
    used = Simulator()
    telemetry(used, "bracing", 3, steps=300, stiffness=450.0)   # stiff: cables break, bob caught
    assert used.status.cable_broken_left or used.status.cable_broken_right
    telemetry(used, "lifting", 3, steps=10)                      # and another scenario in between
    used.reset("bracing", 4)
    assert not (used.status.cable_broken_left or used.status.cable_broken_right)
    again = telemetry(used, "bracing", 4, steps=300)
    fresh = telemetry(Simulator(), "bracing", 4, steps=300)
    assert again.tobytes() == fresh.tobytes()


def test_step_advances_one_control_period():
    sim = Simulator(control_period=0.004, substeps=8)
    sim.reset("idle", 0)
    assert sim.physics.model.opt.timestep == pytest.approx(0.0005)
    for k in range(1, 6):
        sim.step()
        assert sim.sim_time == pytest.approx(0.004 * k, abs=1e-12)


def test_fall_is_reported_once_and_latched():
    sim = Simulator(balance_free=True)
    sim.reset("idle", 0)
    falls = []
    for _ in range(400):
        events = sim.step()
        assert sim.events == events
        falls += [e for e in events if e.kind == FailureKind.FALLEN]
    assert len(falls) == 1 and falls[0].board is None
    assert sim.status.fallen and sim.truth.fallen


def test_boards_are_stable_objects_and_balance_free_survives_resets():
    sim = Simulator()
    sim.reset("idle", 0)
    arm = sim.controller("arm_left")
    sim.balance_free = True
    sim.reset("lifting", 1)
    assert sim.controller("arm_left") is arm
    assert sim.balance_free and sim.controller("wheels").balance_free
    sim.set_wheel_torque(3.0, 3.0)
    sim.step()
    assert abs(sim.axis("wheel_left").current) < 1e-9


def test_readouts_name_every_axis():
    sim = Simulator()
    sim.reset("idle", 0)
    assert tuple(sim.axes()) == AXES
    assert sim.axis("torso").position == pytest.approx(0.0)
    assert np.isnan(sim.truth.impact_momentum) and np.isnan(sim.truth.bottle_height)


def test_api_errors():
    with pytest.raises(ValueError):
        Simulator(control_period=0.01, substeps=5)             # 2 ms timestep
    sim = Simulator()
    with pytest.raises(ConfigStateError):
        sim.step()
    with pytest.raises(UnknownScenarioError):
        sim.reset("juggling", 0)
    with pytest.raises(ValueError):
        sim.reset("idle", -1)
    sim.reset("idle", 0)
    with pytest.raises(UnknownAxisError):
        sim.axis("knee")
    with pytest.raises(UnknownAxisError):
        sim.controller("legs")
    with pytest.raises(RuntimeError):
        sim.trigger_impact()                                   # no pendulum in idle
