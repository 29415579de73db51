"""Bracing and lifting policies: the stiffness map and the checked Hermite spline."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.errors import LimitViolation
from ersac_hil.agent.policies import BracingPolicy, LiftingPolicy, tangent_velocities
from ersac_hil.agent.robot import UBOT
from firmware_sim.controllers.spline import HermiteSpline
from protocol.zenoh import TASKS

LIFT = TASKS["lifting"]
SENSIBLE = (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2)


def test_bracing_stiffness_is_log_linear_between_the_ends():
    p = BracingPolicy()
    assert p.stiffness(0.0) == pytest.approx(p.k_min) and p.k_min == pytest.approx(20.0)
    assert p.stiffness(1.0) == pytest.approx(p.k_max) and p.k_max == pytest.approx(135.0)
    assert p.stiffness(0.5) == pytest.approx(math.sqrt(p.k_min * p.k_max))


@given(a=st.floats(0, 1), b=st.floats(0, 1))
def test_bracing_map_monotone_within_board_ranges_with_constant_damping_time(a, b):
    p = BracingPolicy()
    lo, hi = sorted((a, b))
    assert p.stiffness(lo) <= p.stiffness(hi)
    imp = p.impedance(a)
    for k, d in zip(imp.stiffness, imp.damping):
        assert 0 < k <= UBOT.stiffness_max and 0 < d <= UBOT.damping_max
        assert d / k == pytest.approx(p.damping_time)        # the boards' default D/K, 10 ms
    # the damping ratio rises with stiffness: soft arms are springs, stiff arms well damped
    assert p.damping_ratio(lo)[0] <= p.damping_ratio(hi)[0] + 1e-12
    js, je = UBOT.arm_inertia(p.pose[1])
    assert p.damping_ratio(a)[1] == pytest.approx(imp.damping[1] / (2 * math.sqrt(imp.stiffness[1] * je)))


def test_bracing_map_refuses_impedances_the_boards_refuse():
    with pytest.raises(ValueError):
        BracingPolicy(k_max=UBOT.stiffness_max + 1)
    with pytest.raises(ValueError):
        BracingPolicy(damping_time=UBOT.damping_max / BracingPolicy().k_max * 1.01)


def test_lifting_spline_knots_times_and_tangents():
    p = LiftingPolicy()
    s = p.spline(SENSIBLE)
    assert s.times == pytest.approx([0.0, 1.2, 2.4, 3.6])
    assert s.positions[0] == pytest.approx(p.start) and s.positions[-1] == pytest.approx(p.goal, abs=1e-4)
    assert s.positions[1] == pytest.approx(SENSIBLE[0:2]) and s.positions[2] == pytest.approx(SENSIBLE[2:4])
    assert s.velocities[0] == pytest.approx([0, 0]) and s.velocities[-1] == pytest.approx([0, 0])
    assert s.velocities[1] == pytest.approx((s.positions[2] - s.positions[0]) / 2.4, abs=1e-3)
    q, qd = s.sample(s.times)
    assert q == pytest.approx(s.positions)
    assert qd == pytest.approx(np.vstack([s.velocities[:-1], [[0, 0]]]))
    # quantised to the CAN objects' resolution
    assert np.allclose(s.positions * 1e4, np.round(s.positions * 1e4))
    assert np.allclose(s.velocities * 1e3, np.round(s.velocities * 1e3))
    assert np.allclose(s.times * 1e3, np.round(s.times * 1e3))


def test_goal_pose_holds_the_bottle_at_the_goal_height():
    p = LiftingPolicy()
    assert UBOT.bottle_height(p.goal, p.goal, 0.0) == pytest.approx(p.goal_height)


def test_tangent_method_nonuniform():
    t = np.array([0.0, 1.0, 3.0])
    q = np.array([[0.0], [1.0], [5.0]])
    assert tangent_velocities(t, q)[:, 0] == pytest.approx([0.0, 5.0 / 3.0, 0.0])


def test_violent_or_unreachable_splines_are_refused():
    p = LiftingPolicy()
    with pytest.raises(LimitViolation, match="velocity limit"):
        p.spline((3.0, 0.2, 0.0, 2.4, 0.2, 0.2, 0.2))
    with pytest.raises(LimitViolation, match="shoulder reaches .* outside its range"):
        p.spline((-1.0, 1.0, -0.9, 1.0, 0.5, 0.5, 0.5))  # overshoots past the waypoint at the stop


@settings(max_examples=60, deadline=None)
@given(theta=st.tuples(*(st.floats(lo, hi) for lo, hi in zip(LIFT.lower, LIFT.upper))))
def test_checked_spline_is_the_firmware_trajectory_and_within_limits(theta):
    p = LiftingPolicy()
    try:
        s = p.spline(theta)
    except LimitViolation:
        return
    ref = HermiteSpline.from_knots(s.times, s.positions, s.velocities)
    t = np.linspace(0.0, s.duration + 0.1, 400)
    q, qd = s.sample(t)
    q_fw, qd_fw = ref.sample(t)
    assert q == pytest.approx(q_fw, abs=1e-9) and qd == pytest.approx(qd_fw, abs=1e-9)
    fine_q, fine_qd = s.sample(np.arange(0.0, s.duration, 0.0005))
    assert np.abs(fine_qd).max() <= p.velocity_limit * 1.01
    assert fine_q[:, 0].min() >= UBOT.shoulder_range[0] - 1e-3
    assert fine_q[:, 1].max() <= UBOT.elbow_range[1] + 1e-3
