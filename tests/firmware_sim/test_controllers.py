"""Motor-controller firmware: validated configuration, the impedance law, Hermite splines,
limits, safe state, enable (real MuJoCo underneath)."""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.controllers import (
    ConfigRangeError,
    ConfigStateError,
    HermiteSpline,
    UnknownAxisError,
)
from firmware_sim.plant import AXES, read_motor_params
from firmware_sim.simulator import Simulator

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")


@pytest.fixture(scope="module")
def shared() -> Simulator:
    return Simulator()


@pytest.fixture
def sim(shared) -> Simulator:
    shared.reset("idle", 0)
    return shared


def _joint_torques(sim: Simulator) -> np.ndarray:
    """Joint-side actuator torques the firmware's current settings give at the current state,
    shape (7,) (a fresh forward pass on a copy of the data)."""
    phys = sim.physics
    d = mujoco.MjData(phys.model)
    d.qpos[:], d.qvel[:], d.ctrl[:] = phys.data.qpos, phys.data.qvel, phys.data.ctrl
    mujoco.mj_forward(phys.model, d)
    act = phys.axes.actuator
    return d.actuator_force[act] * phys.model.actuator_gear[act, 0]


# ---- configuration ------------------------------------------------------------------------
bad_floats = st.one_of(
    st.floats(max_value=-1e-6, allow_nan=False), st.floats(min_value=500.0001, allow_nan=False),
    st.just(math.nan), st.just(math.inf))


@settings(max_examples=30, deadline=None)
@given(axis=st.sampled_from(ARM + ("torso",)), stiffness=bad_floats)
def test_out_of_range_stiffness_is_refused_and_changes_nothing(shared, axis, stiffness):
    shared.reset("idle", 0)
    board = shared.controller("torso" if axis == "torso" else f"arm_{axis.split('_')[1]}")
    before = board.impedance(axis)
    gains = shared.physics.model.actuator_gainprm.copy()
    with pytest.raises(ConfigRangeError) as err:
        board.set_impedance(axis, stiffness, 1.0)
    assert err.value.name == f"{axis}.stiffness"
    assert (err.value.low, err.value.high) == (0.0, 500.0)
    assert board.impedance(axis) == before
    assert np.array_equal(shared.physics.model.actuator_gainprm, gains)


@pytest.mark.parametrize("call, name", [
    (lambda s: s.set_impedance("elbow_left", 100.0, 51.0), "elbow_left.damping"),
    (lambda s: s.controller("arm_left").set_position_limits("shoulder_left", -2.0, 1.0),
     "shoulder_left.position_limit_min"),
    (lambda s: s.controller("arm_left").set_position_limits("shoulder_left", 1.0, 0.5),
     "shoulder_left.position_limit_max"),
    (lambda s: s.controller("arm_right").set_velocity_limit("elbow_right", 31.0),
     "elbow_right.velocity_limit"),
    (lambda s: s.controller("wheels").set_current_limit("wheel_left", 10.5), "wheel_left.current_limit"),
    (lambda s: s.controller("torso").set_overcurrent_time(0.0), "torso.overcurrent_time"),
    (lambda s: s.set_wheel_torque(math.nan, 0.0), "wheel_left.torque"),
    (lambda s: s.set_setpoint("torso", math.inf), "torso.setpoint"),
])
def test_other_ranges_are_checked(sim, call, name):
    with pytest.raises(ConfigRangeError) as err:
        call(sim)
    assert err.value.name == name


def test_unknown_axis_and_wrong_board(sim):
    with pytest.raises(UnknownAxisError):
        sim.set_setpoint("knee", 0.0)
    with pytest.raises(UnknownAxisError):
        sim.set_setpoint("wheel_left", 0.0)
    with pytest.raises(UnknownAxisError):
        sim.controller("arm_left").set_setpoint("elbow_right", 0.0)


# ---- the impedance law --------------------------------------------------------------------
@settings(max_examples=10, deadline=None)
@given(k=st.floats(0.0, 500.0), d=st.floats(0.0, 50.0), offset=st.floats(-0.05, 0.05))
def test_joint_torque_is_the_impedance_law(shared, k, d, offset):
    shared.reset("idle", 0)
    for _ in range(3):
        shared.step()                         # the arms move a little: nonzero velocity
    q = shared.axis("elbow_left").position
    shared.set_impedance("elbow_left", k, d)
    shared.set_setpoint("elbow_left", q + offset)
    tau = _joint_torques(shared)[AXES.index("elbow_left")]
    a = shared.axis("elbow_left")
    law = k * (q + offset - a.position) - d * a.velocity
    limit = read_motor_params(shared.physics.model)["elbow_left"].torque_limit
    assert tau == pytest.approx(float(np.clip(law, -limit, limit)), rel=1e-6, abs=1e-9)


def test_safe_state_zeroes_one_board_and_fault_reset_holds_position(sim):
    for axis in ARM:
        sim.set_impedance(axis, 100.0, 2.0)
        sim.set_setpoint(axis, sim.axis(axis).position + 0.1)
    arm = sim.controller("arm_left")
    arm.enter_safe_state("agent heartbeat lost")
    tau = _joint_torques(sim)
    assert tau[AXES.index("shoulder_left")] == 0.0 and tau[AXES.index("elbow_left")] == 0.0
    assert abs(tau[AXES.index("shoulder_right")]) > 5.0
    assert arm.in_safe_state and arm.status("elbow_left").safe_state
    assert arm.safe_state_reason == "agent heartbeat lost"
    for _ in range(20):
        sim.step()                            # the limp arm falls
    assert abs(sim.axis("elbow_left").current) < 1e-9
    arm.clear_faults()
    assert not arm.in_safe_state
    for axis in ("shoulder_left", "elbow_left"):
        assert arm.setpoint(axis) == pytest.approx(sim.axis(axis).position)   # bumpless


def test_disabled_board_gives_no_torque_until_enabled(sim):
    arm = sim.controller("arm_right")
    sim.set_setpoint("shoulder_right", 1.0)
    arm.set_enabled(False)
    tau = _joint_torques(sim)
    assert tau[AXES.index("shoulder_right")] == 0.0
    assert not arm.status("shoulder_right").enabled
    arm.set_enabled(True)
    assert arm.setpoint("shoulder_right") == pytest.approx(sim.axis("shoulder_right").position)


def test_setpoint_is_clamped_to_the_position_limits(sim):
    arm = sim.controller("arm_left")
    arm.set_position_limits("shoulder_left", -0.5, 0.5)
    arm.set_setpoint("shoulder_left", 1.0)
    assert arm.setpoint("shoulder_left") == 0.5
    assert arm.status("shoulder_left").position_limit


# ---- splines ------------------------------------------------------------------------------
knot_times = st.lists(st.floats(0.02, 1.0), min_size=1, max_size=7).map(
    lambda steps: np.concatenate([[0.0], np.cumsum(steps)]))


@settings(max_examples=40, deadline=None)
@given(times=knot_times, data=st.data())
def test_hermite_spline_passes_through_its_knots(times, data):
    n = len(times)
    q = np.array(data.draw(st.lists(st.floats(-3, 3), min_size=n, max_size=n)))
    v = np.array(data.draw(st.lists(st.floats(-5, 5), min_size=n, max_size=n)))
    spline = HermiteSpline.from_knots(times, q, v)
    pos, vel = spline.sample(times[:-1])
    assert np.allclose(pos[:, 0], q[:-1]) and np.allclose(vel[:, 0], v[:-1])
    end_q, end_v = spline.sample(np.array([times[-1], times[-1] + 1.0]))
    assert np.allclose(end_q[:, 0], q[-1]) and np.all(end_v == 0.0)    # holds the last knot
    # continuous position inside: a tiny step moves the reference a tiny bit
    t = (times[0] + times[1]) / 2
    a, _ = spline.sample(np.array([t, t + 1e-7]))
    assert abs(a[1, 0] - a[0, 0]) < 1e-4


@pytest.mark.parametrize("times, name", [
    ([0.0], "spline.knot_count"), (list(np.arange(9) * 0.1), "spline.knot_count"),
    ([0.0, 0.5, 0.5], "spline.times[2]"), ([-0.1, 0.5], "spline.times[0]"),
    ([0.0, 61.0], "spline.times[1]"),
])
def test_invalid_knot_times_are_refused(times, name):
    n = len(times)
    with pytest.raises(ConfigRangeError) as err:
        HermiteSpline.from_knots(times, np.zeros(n), np.zeros(n))
    assert err.value.name == name


def test_spline_outside_the_limits_is_refused_and_the_old_one_kept(sim):
    arm = sim.controller("arm_left")
    good = arm.load_spline([0.0, 1.0], [[0.0, 1.0], [0.5, 1.0]], np.zeros((2, 2)))
    with pytest.raises(ConfigRangeError):
        arm.load_spline([0.0, 1.0], [[0.0, 1.0], [3.5, 1.0]], np.zeros((2, 2)))    # > 3.4 rad
    with pytest.raises(ConfigRangeError):
        arm.load_spline([0.0, 1.0], [[0.0, 1.0], [0.5, 1.0]], [[0.0, 0.0], [11.0, 0.0]])  # > 10 rad/s
    assert arm.spline is good


def test_start_without_a_spline_is_a_state_error(sim):
    with pytest.raises(ConfigStateError):
        sim.controller("arm_right").start_spline()


def test_arm_tracks_a_spline_sampled_at_the_physics_rate(sim):
    arm = sim.controller("arm_left")
    for axis in ("shoulder_left", "elbow_left"):
        arm.set_impedance(axis, 300.0, 8.0)
    q0 = [sim.axis("shoulder_left").position, sim.axis("elbow_left").position]
    q1 = [q0[0] + 0.6, q0[1] - 0.4]
    sim.load_spline("arm_left", [0.0, 0.5], [q0, q1], np.zeros((2, 2)))
    sim.start_spline("arm_left")
    assert arm.status("shoulder_left").spline_active
    ctrl = sim.physics.data.ctrl
    pos_ctrl = sim.physics.axes.ctrl[AXES.index("shoulder_left")]
    refs = []
    for _ in range(130):                    # 0.5 s spline = 100 periods
        sim.step()
        refs.append(ctrl[pos_ctrl])
    assert len(set(refs[:99])) == 99        # a new reference every period (5 per period inside)
    assert not arm.status("shoulder_left").spline_active and arm.status("shoulder_left").spline_done
    assert sim.axis("shoulder_left").position == pytest.approx(q1[0], abs=0.05)
    assert sim.axis("elbow_left").position == pytest.approx(q1[1], abs=0.05)
    assert arm.setpoint("shoulder_left") == pytest.approx(q1[0])


def test_safe_state_of_one_arm_cancels_its_spline_while_the_other_runs(sim):
    q = [sim.axis(axis).position for axis in ARM]
    for board, (a, b) in (("arm_left", (0, 1)), ("arm_right", (2, 3))):
        sim.load_spline(board, [0.0, 2.0], [[q[a], q[b]], [q[a] + 0.3, q[b] + 0.3]], np.zeros((2, 2)))
        sim.start_spline(board)
    sim.step()
    sim.controller("arm_right").enter_safe_state("agent heartbeat lost")  # the second spline
    assert not sim.controller("arm_right").status("elbow_right").spline_active
    assert sim.controller("arm_left").status("elbow_left").spline_active


def test_setpoint_cancels_a_running_spline(sim):
    q = sim.axis("elbow_right").position
    sim.load_spline("elbow_right", [0.0, 2.0], [q, q + 0.5], [0.0, 0.0])
    sim.start_spline("elbow_right")
    sim.step()
    sim.set_setpoint("elbow_right", q)
    status = sim.controller("arm_right").status("elbow_right")
    assert not status.spline_active and not status.spline_done
    assert sim.controller("arm_right").setpoint("elbow_right") == q


def _monitor_arrays(force, threshold, count, counting, over, ticks):
    """The over-current monitor written with whole-array operations only: (limiting, count,
    counting, over-current, latched axes) after one substep with ``force`` (shape (7,))."""
    limiting = np.abs(force) >= threshold
    if not limiting.any():
        return limiting, count * 0 if counting else count, False, over, ()
    count = (count + 1) * limiting
    new = (count >= ticks) & ~over
    return limiting, count, True, over | new, tuple(np.flatnonzero(new).tolist())


_RATIO = st.one_of(st.floats(-3.0, 3.0), st.sampled_from([0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan]))
"""Force over the limiting threshold (exactly at it: 1.0, -1.0)."""


@settings(max_examples=60, deadline=None)
@given(ratios=st.lists(st.lists(_RATIO, min_size=7, max_size=7), min_size=1, max_size=30),
       limits=st.lists(st.floats(0.05, 1.0), min_size=7, max_size=7),
       oc_time=st.sampled_from([0.001, 0.002, 0.005]))
def test_over_current_monitor_agrees_with_whole_array_operations(shared, ratios, limits, oc_time):
    # the monitor's scalar check while no axis limits must change nothing: the same flags,
    # counts and latches substep by substep as the whole-array formulation
    shared.reset("idle", 0)
    fw = shared.controller("wheels")._fw
    fw.current_limit[:] = np.array(limits) * fw.hw_current_limit
    fw.overcurrent_time[:] = oc_time
    fw.push()
    threshold, ticks = fw._sat_threshold.copy(), fw._sat_ticks.copy()
    count, counting, over = np.zeros(7, dtype=np.int64), False, np.zeros(7, dtype=bool)
    act = shared.physics.axes.actuator
    for ratio in ratios:
        force = np.array(ratio) * threshold
        shared.physics.data.actuator_force[act] = force
        limiting, count, counting, over, latched = _monitor_arrays(
            force, threshold, count, counting, over, ticks)
        assert fw.monitor() == latched
        assert np.array_equal(fw.current_limiting, limiting)
        assert np.array_equal(fw._sat_count, count)
        assert np.array_equal(fw.over_current, over)


@settings(max_examples=200)
@given(k=st.integers(1, 3), start=st.integers(0, 4), rows=st.integers(1, 4), seed=st.integers(0, 2 ** 32 - 1),
       gap=st.booleans())
def test_a_spline_written_as_one_slice_writes_what_two_fancy_writes_write(k, start, rows, seed, gap):
    # the firmware writes a running spline's pos and vel inputs as one slice where they
    # interleave (pos, vel, pos, vel ...): the same ctrl, bit for bit, as the two index writes
    from firmware_sim.controllers.firmware import ctrl_block, interleave
    rng = np.random.default_rng(seed)
    pos_ctrl = start + 2 * np.arange(k) + (np.arange(k) > 0) * 2 * gap
    vel_ctrl = pos_ctrl + 1
    q, qd = rng.standard_normal((rows, k)) * 1e3, rng.standard_normal((rows, k))
    block = ctrl_block(pos_ctrl, vel_ctrl)
    assert (block is None) == (gap and k > 1)
    if block is None:
        return
    table = interleave(q, qd)
    for j in range(rows):
        fancy, sliced = np.full(12, np.nan), np.full(12, np.nan)
        fancy[pos_ctrl] = q[j]
        fancy[vel_ctrl] = qd[j]
        sliced[block] = table[j]
        assert fancy.tobytes() == sliced.tobytes()
