"""ersac_hil.agent.robot against the compiled MJCF of the simulated robot (MuJoCo)."""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.robot import UBOT
from firmware_sim.plant.physics import UBOT_XML

ARM_JOINTS = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_path(str(UBOT_XML))


def _jnt(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)


def _body(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


def _pose(model, arms, pitch=0.0):
    """Data with the base upright-then-pitched on its axle at the origin and the arms set."""
    data = mujoco.MjData(model)
    root = model.jnt_qposadr[_jnt(model, "root")]
    data.qpos[root:root + 3] = (0.0, 0.0, UBOT.wheel_radius)
    data.qpos[root + 3:root + 7] = (math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0)
    for name, q in zip(ARM_JOINTS, arms):
        data.qpos[model.jnt_qposadr[_jnt(model, name)]] = q
    mujoco.mj_forward(model, data)
    return data


def test_geometry_and_joint_data(model):
    wheel = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "wheel_left")
    assert model.geom_size[wheel][0] == pytest.approx(UBOT.wheel_radius)
    wl = _body(model, "wheel_left")
    assert model.body_mass[wl] == pytest.approx(UBOT.wheel_mass)
    assert max(model.body_inertia[wl]) == pytest.approx(UBOT.wheel_inertia, rel=1e-6)  # axial
    assert model.body_pos[wl][1] == pytest.approx(UBOT.half_track)
    dof = model.jnt_dofadr[_jnt(model, "wheel_left")]
    assert model.dof_armature[dof] == pytest.approx(UBOT.wheel_armature)
    assert model.dof_damping[dof] == pytest.approx(UBOT.wheel_damping)
    assert model.body_pos[_body(model, "torso")][2] == pytest.approx(UBOT.torso_height)
    assert model.body_pos[_body(model, "upper_arm_left")][2] == pytest.approx(UBOT.shoulder_height)
    assert model.body_pos[_body(model, "forearm_left")][2] == pytest.approx(-UBOT.upper_arm_length)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "hand_left")
    assert model.site_pos[site][2] == pytest.approx(-UBOT.hand_offset)
    for name, rng, arm in (("shoulder_left", UBOT.shoulder_range, UBOT.shoulder_armature),
                           ("elbow_right", UBOT.elbow_range, UBOT.elbow_armature)):
        j = _jnt(model, name)
        assert tuple(model.jnt_range[j]) == pytest.approx(rng)
        assert model.dof_armature[model.jnt_dofadr[j]] == pytest.approx(arm)


def test_elbow_cable_constants_are_the_simulated_ones(model):
    from firmware_sim.plant.damage import CableSpec

    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "elbow_left")
    assert model.actuator_gear[act][0] == pytest.approx(UBOT.elbow_gear)
    assert model.actuator_gainprm[act][1] == pytest.approx(UBOT.elbow_kt)
    spec = CableSpec()
    assert (UBOT.cable_pulley_radius, UBOT.cable_pretension, UBOT.cable_breaking_tension) == (
        spec.pulley_radius, spec.pretension, spec.breaking_tension)
    low, high = (spec.breaking_tension * (1 + k * 3 * spec.strength_cv) for k in (-1, 1))
    assert UBOT.cable_strength_range == pytest.approx((low, high), abs=0.6)  # clipped at +-3 cv
    # the current that holds the median cable at its limit: tension = pretension + kt G |I| / r
    limit = (spec.breaking_tension - spec.pretension) * spec.pulley_radius / (UBOT.elbow_kt * UBOT.elbow_gear)
    assert UBOT.cable_tension(np.array([-limit, 0.0, limit])) == pytest.approx(
        [spec.breaking_tension, spec.pretension, spec.breaking_tension])


def test_wheel_torque_limit_from_motor_constants(model):
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "wheel_left")
    assert model.actuator_gear[act][0] == pytest.approx(UBOT.wheel_gear)
    kt = model.actuator_gainprm[act][1]  # K = sqrt(Kt Ke) = Kt here
    assert kt == pytest.approx(UBOT.wheel_kt)
    assert model.actuator_forcerange[act][1] / kt == pytest.approx(UBOT.wheel_current_limit)
    assert UBOT.wheel_torque_limit == pytest.approx(model.actuator_forcerange[act][1] * UBOT.wheel_gear)


def test_body_mass(model):
    base = _body(model, "base")
    wheels = sum(model.body_mass[_body(model, w)] for w in ("wheel_left", "wheel_right"))
    assert UBOT.body_mass() == pytest.approx(model.body_subtreemass[base] - wheels)


@settings(max_examples=25, deadline=None)
@given(arms=st.tuples(st.floats(-1.0, 3.4), st.floats(-0.1, 2.6),
                      st.floats(-1.0, 3.4), st.floats(-0.1, 2.6)),
       pitch=st.floats(-0.5, 0.5))
def test_hand_and_bottle_height_match_mujoco(model, arms, pitch):
    data = _pose(model, arms, pitch)
    for side, (s, e) in (("left", arms[:2]), ("right", arms[2:])):
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"hand_{side}")
        x, z = UBOT.hand_position(s, e, pitch)
        assert data.site_xpos[site][0] == pytest.approx(float(x), abs=1e-9)
        assert data.site_xpos[site][2] == pytest.approx(float(z) + UBOT.wheel_radius, abs=1e-9)
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"hand_{s}") for s in ("left", "right")]
    assert UBOT.bottle_height(arms[:2], arms[2:], pitch) == pytest.approx(
        data.site_xpos[sites].mean(axis=0)[2], abs=1e-9)


@settings(max_examples=25, deadline=None)
@given(arms=st.tuples(st.floats(-1.0, 3.4), st.floats(-0.1, 2.6),
                      st.floats(-1.0, 3.4), st.floats(-0.1, 2.6)))
def test_body_com_and_inertia_match_mujoco(model, arms):
    data = _pose(model, arms)
    ids = [i for i in range(1, model.nbody) if model.body_rootid[i] == _body(model, "base")
           and model.body(i).name not in ("wheel_left", "wheel_right")]
    m = model.body_mass[ids]
    com = (m[:, None] * data.xipos[ids]).sum(axis=0) / m.sum()
    cx, cz, iyy = UBOT.body_com(arms[:2], arms[2:])
    assert cx == pytest.approx(com[0], abs=1e-9)
    assert cz + UBOT.wheel_radius == pytest.approx(com[2], abs=1e-9)
    inertia = 0.0
    for i, mass in zip(ids, m):
        rot = data.ximat[i].reshape(3, 3)
        world = rot @ np.diag(model.body_inertia[i]) @ rot.T
        d = data.xipos[i] - com
        inertia += world[1, 1] + mass * (d[0] ** 2 + d[2] ** 2)
    assert iyy == pytest.approx(inertia, rel=0.02)  # capsules ~ cylinders


def test_balance_pitch_puts_com_over_axle():
    arms = (0.5, 0.6)
    pitch = UBOT.balance_pitch(arms, arms)
    cx, cz, _ = UBOT.body_com(arms, arms)
    assert cx * math.cos(pitch) + cz * math.sin(pitch) == pytest.approx(0.0, abs=1e-12)
    assert pitch < 0  # arms forward: the body leans back


def test_arm_pose_for_height_reaches_it():
    for elbow in (0.0, 0.3, 0.5):
        q = UBOT.arm_pose_for_height(1.2, elbow)
        assert UBOT.bottle_height((q, elbow), (q, elbow), 0.0) == pytest.approx(1.2)
        x, _ = UBOT.hand_position(q, elbow, 0.0)
        assert q < math.pi and x > 0  # reaching forward-up, not over the head
    with pytest.raises(ValueError):
        UBOT.arm_pose_for_height(2.0, 0.0)


def _body_com_one_arm_at_a_time(robot, left, right, payload):
    """The formulation before the per-cycle cut (each hand by its own numpy call, the inertia
    always): the reference the fast path must equal to the bit."""
    pts = [(p.mass, p.x, p.z, p.iyy) for p in robot.lower_body]
    pts += [(p.mass, p.x, robot.torso_height + p.z, p.iyy) for p in robot.torso_parts]
    hands = []
    for shoulder, elbow in (left, right):
        for link_angle, origin, parts in ((shoulder, (0.0, robot.shoulder_z), robot.upper_arm),
                                          (shoulder + elbow, None, robot.forearm)):
            if origin is None:
                origin = (robot.upper_arm_length * math.sin(shoulder),
                          robot.shoulder_z - robot.upper_arm_length * math.cos(shoulder))
            s, c = math.sin(link_angle), math.cos(link_angle)
            pts += [(p.mass, origin[0] + p.x * c - p.z * s, origin[1] + p.x * s + p.z * c, p.iyy) for p in parts]
        hx, hz = robot.hand_position(shoulder, elbow, 0.0)
        hands.append((float(hx), float(hz)))
    if payload:
        pts.append((payload, 0.5 * (hands[0][0] + hands[1][0]), 0.5 * (hands[0][1] + hands[1][1]), 0.0))
    m, x, z, iyy = (np.array([q[i] for q in pts]) for i in range(4))
    mass = m.sum()
    cx, cz = float((m * x).sum() / mass), float((m * z).sum() / mass)
    return cx, cz, float((iyy + m * ((x - cx) ** 2 + (z - cz) ** 2)).sum())


joint = st.floats(-3.5, 3.5, allow_nan=False)


@settings(max_examples=300)
@given(st.tuples(joint, joint), st.tuples(joint, joint), st.sampled_from([0.0, 0.35, 0.62]) | st.floats(0.0, 2.0))
def test_balance_pitch_and_body_com_are_the_formulation_arm_by_arm_to_the_bit(left, right, payload):
    cx, cz, inertia = _body_com_one_arm_at_a_time(UBOT, left, right, payload)
    assert [v.hex() for v in UBOT.body_com(left, right, payload)] == [cx.hex(), cz.hex(), inertia.hex()]
    assert UBOT.balance_pitch(left, right, payload).hex() == (-math.atan2(cx, cz)).hex()
