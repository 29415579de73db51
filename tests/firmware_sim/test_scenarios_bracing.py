"""Bracing: the strike (momentum from the seed), the fall whatever the wheels do, and the
stiffness trade-off over the agent's range (docs/robot_model.md section 9): soft arms hold the
body deep and never break the elbow cable; stiffer arms hold it with less energy, but from about
three quarters of the range the cable breaks for the larger impacts, and at the stiff end for
every impact."""
from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_sim.scenarios import Bracing
from firmware_sim.simulator import FailureKind, Simulator
from helpers.plant import Balancer, balance_gain

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
SEEDS = range(8)
SOFT, MID, STIFF = 20.0, 84.0, 135.0
"""N m/rad: the ends of the agent's bracing map (ersac_hil/agent/policies.py) and theta 0.75."""
DAMPING_TIME = 0.01
"""s: D = DAMPING_TIME * K, the agent's (and the boards' power-on) damping-to-stiffness ratio."""


@pytest.fixture(scope="module")
def gains() -> np.ndarray:
    return balance_gain("bracing")


def episode(sim: Simulator, gains: np.ndarray, seed: int, stiffness: float | None = None,
            balance_after_strike: bool = False, seconds: float = 2.0) -> dict:
    """One bracing episode: LQR balance until the strike (then zero wheel torque unless
    ``balance_after_strike``), arms at ``stiffness`` with damping DAMPING_TIME * K."""
    sim.reset("bracing", seed)
    if stiffness is not None:
        for axis in ARM:
            sim.set_impedance(axis, stiffness, DAMPING_TIME * stiffness)
    balancer = Balancer(sim, gains)
    hands = np.array([sim.physics.geom_id(g) for g in ("hand_left", "hand_right")])
    shell = np.array([sim.physics.geom_id(g) for g in ("chassis", "battery", "torso",
                                                       "upper_arm_left", "upper_arm_right")])
    acc_sq, energy, hands_down, body_down, events = 0.0, 0.0, False, False, []
    for _ in range(round(seconds / sim.control_period)):
        u = balancer.torque() if balance_after_strike or math.isnan(sim.truth.impact_time) else 0.0
        sim.set_wheel_torque(u, u)
        events += sim.step()
        acc_sq += sim.imu().pitch_acc ** 2 * sim.control_period    # what the agent integrates
        energy += sum(max(s.current * s.voltage, 0.0) for s in map(sim.axis, ARM)) * sim.control_period
        hands_down = hands_down or sim.physics.contacts_with_floor(hands)
        body_down = body_down or sim.physics.contacts_with_floor(shell)
    t = sim.truth
    return dict(momentum=t.impact_momentum, damaged=t.damaged, acc_sq=acc_sq, energy=energy,
                hands_down=hands_down, body_down=body_down,
                peak_tension=max(t.peak_cable_tension_left, t.peak_cable_tension_right),
                events=events, fallen=t.fallen, pitch=t.pitch)


def test_momentum_is_drawn_from_the_seed():
    sim = Simulator()
    drawn = []
    for seed in range(60):
        sim.reset("bracing", seed)
        drawn.append(sim.truth.impact_momentum)
    sim.reset("bracing", 7)
    assert sim.truth.impact_momentum == drawn[7]
    lo, hi = Bracing.momentum_clip
    assert all(lo <= p <= hi for p in drawn)
    assert np.mean(drawn) == pytest.approx(14.0, abs=1.0)
    assert np.std(drawn) == pytest.approx(2.0, rel=0.35)
    assert len(set(drawn)) == len(drawn)


def test_strike_at_quarter_second_or_on_trigger(sim, gains):
    sim.reset("bracing", 0)
    for _ in range(50):
        sim.step()
    assert sim.sim_time == pytest.approx(0.25) and math.isnan(sim.truth.impact_time)
    sim.step()                                    # launched at the start of this period
    assert sim.truth.impact_time == pytest.approx(0.25)
    sim.reset("bracing", 0)
    sim.step()
    sim.trigger_impact()
    assert sim.truth.impact_time == pytest.approx(0.005)
    for _ in range(10):
        sim.step()
    assert sim.truth.pitch_rate > 1.0            # the bob knocked the body forward


@pytest.mark.parametrize("balance_after_strike", [False, True])
def test_the_robot_falls_onto_its_arms_whatever_the_wheels_do(sim, gains, balance_after_strike):
    for seed in (2, 5):                           # the two smallest momenta of SEEDS
        r = episode(sim, gains, seed, balance_after_strike=balance_after_strike, seconds=1.5)
        assert r["hands_down"], r


def test_stiffness_trade_off_over_seeds(sim, gains):
    soft = [episode(sim, gains, s, stiffness=SOFT) for s in SEEDS]
    mid = [episode(sim, gains, s, stiffness=MID) for s in SEEDS]
    stiff = [episode(sim, gains, s, stiffness=STIFF) for s in SEEDS]
    print("\nseed momentum | soft: acc_sq E T_peak pitch damaged | mid: ... | stiff: ...")
    for s, *rs in zip(SEEDS, soft, mid, stiff):
        print(f"{s} {rs[0]['momentum']:.2f} | " + " | ".join(
            f"{r['acc_sq']:.0f} {r['energy']:.1f} {r['peak_tension']:.0f} {r['pitch']:.2f} {r['damaged']}"
            for r in rs))
    damaged = [r for r in mid if r["damaged"]]
    intact = [r for r in mid if not r["damaged"]]
    assert not any(r["damaged"] for r in soft)            # soft arms never break the cable
    assert 1 <= len(damaged) <= len(SEEDS) - 1            # theta 0.75 breaks it for some seeds
    assert all(r["damaged"] for r in stiff)               # the stiff end for every seed
    assert all(a["peak_tension"] < b["peak_tension"] < c["peak_tension"]
               for a, b, c in zip(soft, mid, stiff) if not b["damaged"])
    # damage goes with the larger strikes
    assert min(r["momentum"] for r in damaged) > max(r["momentum"] for r in intact)
    # soft arms hold the body, but deep: the arms deflect far, the body sinks lower and holding
    # the deflected arms costs far more energy than on intact stiffer arms; nothing hard touches
    # the floor (the collapse cliff lies below the agent's range)
    assert not any(r["body_down"] for r in soft)
    assert np.mean([r["pitch"] for r in soft]) > np.mean([r["pitch"] for r in intact]) + 0.2
    assert min(r["energy"] for r in soft) > max(r["energy"] for r in intact) + 10.0
    # with the agent's weights the soft end costs more than intact stiffer arms, and a break costs
    # more than any intact catch: the arm goes limp and the body lands
    cost = lambda r: 10 * r["damaged"] + 0.1 * r["acc_sq"] + 5 * r["energy"]
    assert np.mean([cost(r) for r in soft]) > np.mean([cost(r) for r in intact]) + 50.0
    assert min(cost(r) for r in damaged + stiff) > max(cost(r) for r in intact) + 10.0
    # each break is reported once, by the arm board of its side
    for r in damaged + stiff:
        breaks = [e for e in r["events"] if e.kind == FailureKind.CABLE_BROKEN]
        assert 1 <= len(breaks) <= 2
        assert len({e.axis for e in breaks}) == len(breaks)
        assert all(e.board == f"arm_{e.axis.split('_')[1]}" for e in breaks)


def test_a_broken_cable_leaves_the_elbow_limp(sim, gains):
    r = episode(sim, gains, 0, stiffness=STIFF, seconds=1.0)
    assert r["damaged"]
    status = sim.status
    side = "left" if status.cable_broken_left else "right"
    assert sim.controller(f"arm_{side}").status(f"elbow_{side}").disconnected
    assert abs(sim.axis(f"elbow_{side}").current) < 1e-9
    assert getattr(sim.truth, f"cable_tension_{side}") == 0.0
    sim.set_impedance(f"elbow_{side}", 100.0, 1.0)      # reconfiguring does not repair it
    sim.step()
    assert abs(sim.axis(f"elbow_{side}").current) < 1e-9
