"""DC motor model seen through the telemetry: I = tau / (Kt G), V = I R + Ke G omega, current
saturation, supply clamp and the over-current fault (open loop, real MuJoCo)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.plant import MotorBank, read_motor_params
from firmware_sim.simulator import FailureKind, Simulator


@pytest.fixture
def sim() -> Simulator:
    s = Simulator()
    s.reset("idle", 0)
    return s


def test_wheel_current_and_voltage_follow_the_motor_model(sim):
    p = read_motor_params(sim.physics.model)["wheel_left"]
    tau = 1.5
    sim.set_wheel_torque(tau, 0.0)
    speeds = []
    for _ in range(60):
        sim.step()
        a = sim.axis("wheel_left")
        assert a.current == pytest.approx(tau / (p.kt * p.gear), rel=1e-9)
        # the voltage belongs to the period's last substep, the speed to its end: allow the
        # speed change of one substep
        back_emf = p.ke * p.gear * a.velocity
        assert a.voltage == pytest.approx(a.current * p.resistance + back_emf, abs=0.05)
        speeds.append(a.velocity)
        right = sim.axis("wheel_right")
        assert abs(right.current) < 1e-9
    assert speeds[-1] > 1.0                                  # the wheel spins up forward ...
    a = sim.axis("wheel_left")
    assert a.voltage > 2 * a.current * p.resistance         # ... and back-EMF dominates


def test_current_saturates_at_the_limit_and_over_current_latches_once(sim):
    p = read_motor_params(sim.physics.model)["wheel_left"]
    wheels = sim.controller("wheels")
    wheels.set_overcurrent_time(0.02)
    sim.set_wheel_torque(15.0, -15.0)                       # beyond Kt G Imax = 7.85 N m
    over = []
    for k in range(8):
        over += [e for e in sim.step() if e.kind == FailureKind.OVER_CURRENT]
        for axis in ("wheel_left", "wheel_right"):
            a = sim.axis(axis)
            assert abs(a.current) == pytest.approx(p.current_limit)
            assert abs(a.voltage) <= p.supply_voltage + 1e-9
            assert wheels.status(axis).current_limiting
    assert sorted(e.axis for e in over) == ["wheel_left", "wheel_right"]    # once per axis
    assert all(e.board == "wheels" and 0.02 <= e.sim_time <= 0.026 for e in over)
    assert sim.status.over_current and set(sim.status.over_current_axes) == {"wheel_left", "wheel_right"}
    sim.set_wheel_torque(0.0, 0.0)
    sim.step()
    wheels.clear_faults()
    assert not sim.status.over_current


def test_lower_configured_current_limit_lowers_the_torque(sim):
    sim.controller("wheels").set_current_limit("wheel_left", 2.0)
    sim.set_wheel_torque(5.0, 0.0)
    sim.step()
    assert sim.axis("wheel_left").current == pytest.approx(2.0)


def test_supply_voltage_bounds_the_speed():
    sim = Simulator()
    sim.reset("idle", 0)
    p = read_motor_params(sim.physics.model)["torso"]
    # torso yaw is free to spin: drive it with a far setpoint and a stiff law
    torso = sim.controller("torso")
    torso.set_impedance("torso", 500.0, 0.0)
    torso.set_setpoint("torso", 2.5)
    top = 0.0
    for _ in range(40):
        sim.step()
        a = sim.axis("torso")
        assert abs(a.voltage) <= p.supply_voltage + 1e-9
        top = max(top, a.velocity)
    assert 0.5 * p.no_load_speed < top <= p.no_load_speed


_SEVEN = st.lists(st.one_of(st.floats(-1e3, 1e3), st.floats(allow_nan=True, allow_infinity=True)),
                  min_size=7, max_size=7)


@pytest.fixture(scope="module")
def bank() -> MotorBank:
    s = Simulator()
    s.reset("idle", 0)
    return MotorBank(read_motor_params(s.physics.model))


@settings(max_examples=200)
@given(torque=_SEVEN, speed=_SEVEN)
def test_the_motor_readouts_axis_by_axis_are_the_whole_array_formula_bit_for_bit(bank, torque, speed):
    # current and voltage are computed value by value: exactly what the array formula gives
    with np.errstate(all="ignore"):  # overflow to inf, inf - inf: what the values give
        current = np.array(torque) / bank.kt
        voltage = current * bank.resistance + bank.ke * np.array(speed)
    assert np.array(bank.current(torque)).tobytes() == current.tobytes()
    assert np.array(bank.voltage(bank.current(torque), speed)).tobytes() == voltage.tobytes()
