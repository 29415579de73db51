"""The uBot MJCF: named axes as DC motors, masses and dimensions, motor constants, integrator,
and the balanced initial states of every scenario (real MuJoCo)."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.plant import AXES, UBOT_XML, WHEEL_RADIUS, read_motor_params
from firmware_sim.simulator import Simulator


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(UBOT_XML))


def test_every_axis_is_a_named_joint_driven_by_a_dcmotor(model):
    for axis in AXES:
        joint = model.joint(axis)
        act = model.actuator(axis)
        assert model.actuator_trnid[act.id, 0] == joint.id
        assert model.actuator_gaintype[act.id] == mujoco.mjtGain.mjGAIN_DCMOTOR
        assert model.actuator_biastype[act.id] == mujoco.mjtBias.mjBIAS_DCMOTOR


def test_integrator_and_timestep(model):
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.opt.timestep <= 1e-3


def test_mass_wheels_and_shoulder_height():
    sim = Simulator()
    sim.reset("idle", 0)
    phys = sim.physics
    assert phys.robot_mass() == pytest.approx(19.0, abs=0.5)
    wheel = phys.model.geom_size[phys.geom_id("wheel_left")]
    assert wheel[0] == pytest.approx(WHEEL_RADIUS) == pytest.approx(0.1)
    for side in ("left", "right"):
        shoulder_z = phys.data.xpos[phys.body_id(f"upper_arm_{side}")][2]
        assert shoulder_z == pytest.approx(0.6, abs=0.05)


# Kt = Ke (N m/A), R (ohm), gear, current limit (A) per axis, as in docs/robot_model.md
MOTORS = {
    "wheel_left": (0.0302, 0.299, 26, 10.0), "wheel_right": (0.0302, 0.299, 26, 10.0),
    "torso": (0.0259, 0.611, 100, 4.0),
    "shoulder_left": (0.0259, 0.611, 160, 12.0), "shoulder_right": (0.0259, 0.611, 160, 12.0),
    "elbow_left": (0.0259, 0.611, 120, 12.0), "elbow_right": (0.0259, 0.611, 120, 12.0),
}


def test_motor_constants_read_back_from_the_compiled_model(model):
    params = read_motor_params(model)
    assert set(params) == set(AXES)
    for axis, (kt, r, gear, imax) in MOTORS.items():
        p = params[axis]
        assert (p.kt, p.ke, p.resistance, p.gear) == pytest.approx((kt, kt, r, gear))
        assert p.current_limit == pytest.approx(imax)
        assert p.supply_voltage == pytest.approx(24.0)
        assert p.torque_limit == pytest.approx(kt * gear * imax)
        assert p.rotor_inertia > 0


@pytest.mark.parametrize("scenario", ["idle", "bracing", "lifting"])
def test_each_scenario_starts_at_rest_in_static_balance(scenario):
    sim = Simulator()
    sim.reset(scenario, 0)
    phys = sim.physics
    d = phys.data
    bodies = [phys.base_id]
    if scenario == "lifting":
        bodies.append(phys.body_id("bottle/shell"))
    com = phys.com(tuple(bodies))
    axle = d.xpos[phys.base_id]
    assert abs(com[0] - axle[0]) < 1e-3            # centre of mass above the wheel axle
    assert np.all(d.qvel == 0.0)
    assert abs(d.qacc[phys.model.body_dofadr[phys.base_id] + 2]) < 0.05  # wheels carry the weight
    assert sim.sim_time == 0.0


@settings(max_examples=30, deadline=None)
@given(scenario=st.sampled_from(["idle", "bracing", "lifting"]), seed=st.integers(0, 2 ** 31),
       periods=st.integers(0, 120), torque=st.floats(-8.0, 8.0), pick=st.data())
def test_floor_contact_check_agrees_with_the_contact_arrays(scenario, seed, periods, torque, pick):
    # the pair loop of contacts_with_floor against MuJoCo's contact arrays masked whole
    sim = Simulator()
    sim.reset(scenario, seed)
    sim.set_wheel_torque(torque, torque)
    for _ in range(periods):
        sim.step()
    phys = sim.physics
    ngeom = phys.model.ngeom
    mask = np.array(pick.draw(st.lists(st.booleans(), min_size=ngeom, max_size=ngeom)))
    c, floor = phys.data.contact, phys.floor_geom_id
    expected = bool(mask[c.geom2[c.geom1 == floor]].any() or mask[c.geom1[c.geom2 == floor]].any())
    assert phys.contacts_with_floor(mask) is expected
    assert phys.contacts_with_floor(np.flatnonzero(mask)) is expected
    assert phys.contacts_with_floor(frozenset(np.flatnonzero(mask).tolist())) is expected
