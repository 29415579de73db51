"""Cost terms: analytic integrals over synthetic traces, names and units of the contract
(the pure term functions of ``costs`` and the tasks that report them)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.agent import costs
from ersac_hil.agent.policies import LiftingPolicy
from ersac_hil.agent.tasks import BracingTask, EmcyMark, LiftingTask
from ersac_hil.agent.robot import UBOT
from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Trace
from protocol.can.objects import EmcyCode, Status
from protocol.zenoh import TASKS

DT = 0.005


def trace(n=400, **arrays) -> Trace:
    base = {name: np.zeros((n, len(JOINTS))) for name in ("position", "velocity", "current", "voltage")}
    base |= {name: np.zeros(n) for name in ("pitch", "pitch_rate", "pitch_acc", "acc_x", "acc_z")}
    base["status"] = np.ones((n, len(STATUS_DEVICES)), dtype=np.int64)
    base |= arrays
    return Trace(dt=DT, **base)


@given(acc=st.floats(-50, 50), amps=st.floats(-5, 5), volts=st.floats(-24, 24))
def test_bracing_terms_are_the_integrals(acc, amps, volts):
    n = 400
    cur = np.zeros((n, 7))
    volt = np.zeros((n, 7))
    cur[:, 3:] = amps
    volt[:, 3:] = volts
    cur[:, :3] = 100.0  # wheels and torso do not count as arm power
    volt[:, :3] = 10.0
    tr = trace(n, pitch_acc=np.full(n, acc), current=cur, voltage=volt)
    terms = BracingTask().cost_terms(tr)
    assert list(terms) == list(TASKS["bracing"].term_names)
    assert terms["body_acc_sq"] == pytest.approx(acc * acc * 2.0)
    # consumed energy: a generating motor (I*V < 0) counts zero, never a credit
    assert terms["arm_power"] == pytest.approx(4 * max(amps * volts, 0.0) * 2.0, abs=1e-9)
    assert terms["damage"] == 0.0


def test_consumed_energy_is_clipped_per_motor_not_after_summing():
    n = 100
    cur = np.zeros((n, 7))
    volt = np.zeros((n, 7))
    cur[:, 3], volt[:, 3] = 2.0, 10.0      # shoulder_left drives: +20 W
    cur[:, 4], volt[:, 4] = -2.0, 15.0     # elbow_left back-driven, generating: -30 W
    tr = trace(n, current=cur, voltage=volt)
    assert costs.arm_power(tr) == pytest.approx(20.0 * n * DT)   # not (20 - 30) W, not 0
    assert costs.power(tr) == pytest.approx(20.0 * n * DT)
    assert costs.summary(tr)["energy_j"] == pytest.approx(20.0 * n * DT)


def test_damage_from_status_bit_or_emcy():
    n = 50
    status = np.ones((n, 5), dtype=np.int64)
    assert costs.damage(trace(n, status=status)) == 0.0
    status[30, STATUS_DEVICES.index("arm_left")] |= Status.CABLE_BROKEN
    assert costs.damage(trace(n, status=status)) == 1.0
    assert costs.damage(trace(n), emcy_codes=[EmcyCode.CABLE_BROKEN]) == 1.0
    assert costs.damage(trace(n), emcy_codes=[EmcyCode.FALLEN]) == 0.0


def test_lifting_terms_rolling_robot():
    n = 200
    t = np.arange(n) * DT
    omega, r = 2.0, UBOT.wheel_radius
    pitch = np.full(n, 0.1)
    pos = np.zeros((n, 7))
    vel = np.zeros((n, 7))
    pos[:, 0:2] = (omega * t - 0.1)[:, None]  # absolute wheel angle = omega t
    vel[:, 0:2] = omega
    goal = LiftingPolicy().goal
    pos[:, 3:5] = goal
    pos[:, 5:7] = goal
    tr = trace(n, position=pos, velocity=vel, pitch=pitch)
    terms = LiftingTask().cost_terms(tr)
    dm = 10.0  # lengths in decimetres, angles in rad
    assert list(terms) == list(TASKS["lifting"].term_names)
    assert terms["x_wheel_sq"] == pytest.approx(np.sum((dm * r * omega * t) ** 2) * DT)
    assert terms["xdot_wheel_sq"] == pytest.approx((dm * r * omega) ** 2 * n * DT)
    assert terms["alpha_sq"] == pytest.approx(0.01 * n * DT)
    assert terms["alphadot_sq"] == 0.0
    h = UBOT.bottle_height(goal, goal, 0.1)
    assert terms["h_error_sq"] == pytest.approx((dm * (1.2 - h)) ** 2 * n * DT)
    assert terms["power"] == 0.0
    total = TASKS["lifting"].total_cost(terms)
    assert total == pytest.approx(sum(TASKS["lifting"].default_weights[k] * v for k, v in terms.items()))


def _arms_at_goal(n: int) -> Trace:
    """n cycles, upright, both arms holding the lifting goal pose."""
    pos = np.zeros((n, 7))
    goal = LiftingPolicy().goal
    pos[:, 3:5] = goal
    pos[:, 5:7] = goal
    return trace(n, position=pos)


def test_bottle_height_zero_error_upright_at_goal():
    tr = _arms_at_goal(10)
    assert costs.h_error_sq(costs.bottle_height(tr), 1.2, DT) == pytest.approx(0.0, abs=1e-12)


def test_a_dropped_bottle_lies_on_the_floor_from_its_emcy_on():
    n = 100
    tr = _arms_at_goal(n)  # the hands stay at the goal height
    task = LiftingTask()
    held = task.cost_terms(tr)["h_error_sq"]
    dropped = task.cost_terms(tr, [EmcyMark(EmcyCode.FALLEN, 10), EmcyMark(EmcyCode.BOTTLE_DROPPED, 60),
                                   EmcyMark(EmcyCode.BOTTLE_DROPPED, 61)])["h_error_sq"]
    assert held == pytest.approx(0.0, abs=1e-12)
    assert dropped == pytest.approx((1.2 - task.floor_height_m) ** 2 * 40 * DT / task.length_unit_m ** 2)


def test_summary_figures_are_finite_and_named():
    s = costs.summary(trace(20, pitch=np.linspace(-0.2, 0.1, 20)))
    assert s["n_cycles"] == 20 and s["max_abs_pitch"] == pytest.approx(0.2)
    assert all(np.isfinite(v) for v in s.values())
    assert costs.summary(trace(0)) == {"n_cycles": 0.0}
    assert "final_bottle_height_m" not in s  # a lifting figure (LiftingTask.summary)
    assert LiftingTask().summary(trace(0)) == {}
