"""Lifting: the bottle starts near the ground in a rigid two-handed grasp; a smooth arm spline
lifts it to ~1.2 m while an LQR balances; a too-low spline misses the height; a violent one
breaks the grasp; the hidden liquid moves the bottle's centre of mass."""
from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.scenarios import Lifting
from firmware_sim.simulator import FailureKind, Simulator
from helpers.plant import Balancer, balance_gain

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
START = (Lifting.pose["shoulder_left"], Lifting.pose["elbow_left"])


@pytest.fixture(scope="module")
def gains() -> np.ndarray:
    return balance_gain("idle")


def lift(sim: Simulator, gains: np.ndarray, times, shoulder, elbow, seconds: float = 4.0,
         stiffness: float = 150.0, damping: float = 5.0) -> dict:
    """Both arms follow the spline through (shoulder, elbow) knots (tangent-method knot
    velocities, zero at the ends) while the LQR balances."""
    sim.reset("lifting", 0)
    for axis in ARM:
        sim.set_impedance(axis, stiffness, damping)
    t = np.asarray(times, dtype=float)
    q = np.stack([shoulder, elbow], axis=1).astype(float)
    v = np.zeros_like(q)
    v[1:-1] = (q[2:] - q[:-2]) / (t[2:] - t[:-2])[:, None]
    for board in ("arm_left", "arm_right"):
        sim.load_spline(board, t, q, v)
    sim.start_spline()
    balancer = Balancer(sim, gains)
    heights, events = [], []
    for _ in range(round(seconds / sim.control_period)):
        u = balancer.torque()
        sim.set_wheel_torque(u, u)
        events += sim.step()
        heights.append(sim.truth.bottle_height)
    return dict(final=heights[-1], peak=max(heights), events=events, truth=sim.truth)


def test_bottle_starts_near_the_ground_in_the_hands(sim):
    sim.reset("lifting", 0)
    t = sim.truth
    assert 0.1 < t.bottle_height < 0.25
    assert t.bottle_com[2] == pytest.approx(t.bottle_height - 0.006, abs=0.002)  # liquid low
    phys = sim.physics
    hands = phys.data.site_xpos[[phys.site_id("hand_left"), phys.site_id("hand_right")]]
    assert np.allclose(hands.mean(axis=0), phys.data.xpos[phys.body_id("bottle/shell")], atol=1e-6)
    assert not t.bottle_dropped


def test_smooth_lift_reaches_the_goal_height(sim, gains):
    r = lift(sim, gains, [0.0, 1.5, 3.0], [START[0], 1.6, 3.1], [START[1], 1.8, 0.1])
    assert r["final"] == pytest.approx(Lifting.goal_height, abs=0.08)
    assert not r["truth"].bottle_dropped and not r["truth"].fallen
    assert not [e for e in r["events"] if e.kind == FailureKind.BOTTLE_DROPPED]


def test_too_low_spline_misses_the_height(sim, gains):
    r = lift(sim, gains, [0.0, 1.5, 3.0], [START[0], 1.0, 1.8], [START[1], 1.5, 1.0])
    assert r["final"] < Lifting.goal_height - 0.1
    assert not r["truth"].bottle_dropped


def test_violent_lift_breaks_the_grasp(sim, gains):
    # seconds: the grip limit varies with the seed; a grasp that holds longer throws the bottle
    # further, and it needs more than a second to land
    r = lift(sim, gains, [0.0, 0.3, 0.6], [START[0], 1.6, 3.1], [START[1], 1.8, 0.1], seconds=2.5)
    drops = [e for e in r["events"] if e.kind == FailureKind.BOTTLE_DROPPED]
    assert len(drops) == 1 and drops[0].sim_time < 0.6
    assert r["truth"].bottle_dropped and sim.status.bottle_dropped
    assert r["final"] < 0.15                       # it fell to the floor


def test_grip_limit_varies_between_episodes_around_the_nominal_limit(sim):
    def grip(seed: int) -> float:
        sim.reset("lifting", seed)
        return sim._require().scenario.grip_limit

    limits = [grip(seed) for seed in range(40)]
    assert grip(3) == limits[3]                    # a pure function of the seed
    nominal, spread = Lifting.grasp_force_limit, Lifting.grip_spread
    assert abs(np.mean(limits) - nominal) < 2.5 * nominal * spread / np.sqrt(40)
    assert 0.5 * spread < np.std(limits) / nominal < 1.5 * spread
    assert min(limits) >= nominal * (1 - 2.5 * spread) and max(limits) <= nominal * (1 + 2.5 * spread)


def test_sloshing_liquid_moves_the_centre_of_mass(sim):
    sim.reset("lifting", 0)
    body = sim.physics.body_id("bottle/shell")

    def com_in_bottle() -> np.ndarray:
        d = sim.physics.data
        return d.xmat[body].reshape(3, 3).T @ (np.asarray(sim.truth.bottle_com) - d.xpos[body])

    at_rest = com_in_bottle()
    assert abs(at_rest[0]) < 1e-3
    offsets = []
    for k in range(60):                           # jerk the robot forward, then back
        u = 5.0 if k < 15 else -5.0 if k < 30 else 0.0
        sim.set_wheel_torque(u, u)
        sim.step()
        offsets.append(com_in_bottle()[0])
    assert max(np.abs(offsets)) > 0.004            # several mm: the 0.6 kg liquid swings
    assert not sim.truth.bottle_dropped
