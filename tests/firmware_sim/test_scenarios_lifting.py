"""Lifting: the bottle starts near the ground in a rigid two-handed grasp; a smooth arm spline
lifts it to ~1.2 m while an LQR balances; a too-low spline misses the height; a violent one
breaks the grasp; the torque-limited shoulders stall a slow straight lift near shoulder height
while the same path swung in 2 s gets over; the fill of the bottle varies per episode from a
stream of its own; the hidden liquid moves the bottle's centre of mass."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.plant.motors import read_motor_params
from firmware_sim.scenarios import Lifting
from firmware_sim.scenarios.lifting import fill_factor
from firmware_sim.simulator import FailureKind, Simulator
from helpers.plant import Balancer, balance_gain
from protocol.zenoh.tasks import LIFTING_GOAL_HEIGHT_M

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
START = (Lifting.pose["shoulder_left"], Lifting.pose["elbow_left"])


@pytest.fixture(scope="module")
def gains() -> np.ndarray:
    return balance_gain("idle")


def lift(sim: Simulator, gains: np.ndarray, times, shoulder, elbow, seconds: float = 4.0,
         stiffness: float = 150.0, damping: float = 5.0, seed: int = 0) -> dict:
    """Both arms follow the spline through (shoulder, elbow) knots (tangent-method knot
    velocities, zero at the ends) while the LQR balances."""
    sim.reset("lifting", seed)
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
    assert r["final"] == pytest.approx(LIFTING_GOAL_HEIGHT_M, abs=0.08)
    assert not r["truth"].bottle_dropped and not r["truth"].fallen
    assert not [e for e in r["events"] if e.kind == FailureKind.BOTTLE_DROPPED]


def test_too_low_spline_misses_the_height(sim, gains):
    r = lift(sim, gains, [0.0, 1.5, 3.0], [START[0], 1.0, 1.8], [START[1], 1.5, 1.0])
    assert r["final"] < LIFTING_GOAL_HEIGHT_M - 0.1
    assert not r["truth"].bottle_dropped


def test_violent_lift_breaks_the_grasp(sim, gains):
    # seconds: the grip limit varies with the seed; a grasp that holds longer throws the bottle
    # further, and it needs more than a second to land. The current-limited shoulders lag the
    # 0.6 s spline: the arm swings over at ~5 rad/s and the grasp breaks as it brakes (~1.1 s)
    r = lift(sim, gains, [0.0, 0.3, 0.6], [START[0], 1.6, 3.1], [START[1], 1.8, 0.1], seconds=2.5)
    drops = [e for e in r["events"] if e.kind == FailureKind.BOTTLE_DROPPED]
    assert len(drops) == 1 and drops[0].sim_time < 1.2
    assert r["truth"].bottle_dropped and sim.status.bottle_dropped
    assert r["final"] < 0.15                       # it fell to the floor


#: a straight line in joint space from the start to the goal pose (shoulder pi - 0.24 rad,
#: elbow 0.3) through its midpoint, over ``duration`` seconds
LINE = (np.array([START[0], 1.45, 2.9]), np.array([START[1], 0.62, 0.3]))


def line_lift(sim: Simulator, gains: np.ndarray, duration: float, seed: int) -> dict:
    return lift(sim, gains, [0.0, duration / 2, duration], *LINE, seconds=duration + 2.0, seed=seed)


@pytest.mark.parametrize("seed", [0, 7])
def test_slow_lift_stalls_near_shoulder_height(sim, gains, seed):
    # quasi-static: the current-limited shoulders cannot hold the bottle near the horizontal
    r = line_lift(sim, gains, 6.0, seed)
    assert r["final"] < 0.75 and r["peak"] < 0.8    # the shoulders are 0.62 m above the floor
    assert not r["truth"].bottle_dropped and not r["truth"].fallen
    assert {e.axis for e in r["events"] if e.kind == FailureKind.OVER_CURRENT} >= {"shoulder_left",
                                                                                  "shoulder_right"}


@pytest.mark.parametrize("seed", [0, 7])
def test_the_same_path_swung_in_two_seconds_gets_over(sim, gains, seed):
    r = line_lift(sim, gains, 2.0, seed)
    assert r["final"] == pytest.approx(LIFTING_GOAL_HEIGHT_M, abs=0.05)
    assert not r["truth"].bottle_dropped and not r["truth"].fallen


def test_shoulders_are_current_limited_on_the_lifting_bench_only(sim):
    sim.reset("lifting", 0)
    lifting = read_motor_params(sim.physics.model)["shoulder_left"]
    sim.reset("bracing", 0)
    bracing = read_motor_params(sim.physics.model)["shoulder_left"]
    assert lifting.current_limit == pytest.approx(Lifting.shoulder_current_limit)
    assert bracing.current_limit == pytest.approx(12.0)
    assert lifting.torque_limit < 0.2 * bracing.torque_limit


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**32 - 1))
def test_fill_is_drawn_from_its_own_stream_of_the_seed(sim, seed):
    sim.reset("lifting", seed)
    first = sim.truth.liquid_mass
    streams = np.random.SeedSequence(seed).spawn(4)
    assert first == 0.6 * fill_factor(np.random.default_rng(streams[3]), Lifting.fill_spread)
    assert 0.6 * (1 - 2.5 * Lifting.fill_spread) <= first <= 0.6 * (1 + 2.5 * Lifting.fill_spread)
    # the grip limit is still the first draw of the scenario stream, as before the fill existed
    z = np.clip(np.random.default_rng(streams[0]).standard_normal(), -2.5, 2.5)
    assert sim._require().scenario.grip_limit == Lifting.grasp_force_limit * (1 + Lifting.grip_spread * z)
    sim.reset("bracing", seed)
    assert np.isnan(sim.truth.liquid_mass)
    sim.reset("lifting", seed)
    assert sim.truth.liquid_mass == first           # a pure function of the seed
    mass = sim.physics.model.body_mass[sim.physics.body_id("bottle/liquid")]
    assert mass == first


def test_fill_varies_between_episodes_around_the_nominal_mass(sim):
    def fill(seed: int) -> float:
        sim.reset("lifting", seed)
        return sim.truth.liquid_mass

    masses = np.array([fill(seed) for seed in range(40)]) / 0.6
    spread = Lifting.fill_spread
    assert abs(masses.mean() - 1.0) < 2.5 * spread / np.sqrt(40)
    assert 0.5 * spread < masses.std() < 1.5 * spread


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
