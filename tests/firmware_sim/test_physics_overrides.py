"""Named physical overrides (``firmware_sim.plant.overrides``, ``ersac-hil sim --physics FILE``):
every refused value is refused with one line naming it, and every accepted one acts on the
compiled plant, the cables or the scenario."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.plant.damage import CableSpec
from firmware_sim.plant.motors import read_motor_params
from firmware_sim.plant.overrides import PARAMETERS, PhysicsError, PhysicsOverrides
from firmware_sim.simulator import Simulator

NAMES = sorted(PARAMETERS)


# ------------------------------------------------------------------ refusals
@given(st.text(min_size=1, max_size=40).filter(lambda s: s not in PARAMETERS and "." not in s))
def test_an_unknown_name_is_refused_naming_it(name):
    with pytest.raises(PhysicsError, match="unknown physical parameter") as info:
        PhysicsOverrides.from_mapping({name: 1.0})
    assert repr(name) in str(info.value) and "\n" not in str(info.value)


@given(st.sampled_from(NAMES), st.text(min_size=1, max_size=20).filter(lambda s: "." not in s))
def test_an_unknown_name_next_to_a_known_one_is_refused(known, extra):
    name = known.rsplit(".", 1)[0] + "." + extra
    if name in PARAMETERS:
        return
    with pytest.raises(PhysicsError, match="unknown physical parameter"):
        PhysicsOverrides.from_mapping({name: 1.0})


@st.composite
def out_of_range(draw):
    name = draw(st.sampled_from(NAMES))
    q = PARAMETERS[name]
    span = q.hi - q.lo
    value = draw(st.one_of(
        st.floats(max_value=q.lo, exclude_max=True, allow_nan=False, allow_infinity=False,
                  min_value=q.lo - 10 * span - 1),
        st.floats(min_value=q.hi, exclude_min=True, allow_nan=False, allow_infinity=False,
                  max_value=q.hi + 10 * span + 1),
        st.sampled_from([math.nan, math.inf, -math.inf])))
    return name, value


@given(out_of_range())
def test_a_value_outside_its_range_is_refused_naming_the_entry_and_range(case):
    name, value = case
    with pytest.raises(PhysicsError) as info:
        PhysicsOverrides.from_mapping({name: value})
    msg = str(info.value)
    assert msg.startswith(f"{name} = ") and "outside [" in msg and "\n" not in msg


@given(st.sampled_from(NAMES), st.one_of(st.text(max_size=5), st.booleans(), st.lists(st.floats(), max_size=2)))
def test_a_value_that_is_not_a_number_is_refused(name, value):
    with pytest.raises(PhysicsError, match=f"{name} must be a number"):
        PhysicsOverrides.from_mapping({name: value})


@given(st.floats(100.0, 1000.0))
def test_a_pretension_at_or_above_the_breaking_tension_is_refused(breaking):
    with pytest.raises(PhysicsError, match="pretension must stay below"):
        PhysicsOverrides.from_mapping({"cable": {"breaking_tension": breaking, "pretension": min(breaking, 1000.0)}})


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture], max_examples=30)
@given(st.sampled_from(NAMES), st.data())
def test_every_value_in_range_is_accepted(name, data):
    q = PARAMETERS[name]
    v = data.draw(st.floats(q.lo, q.hi))
    extra = {"cable.breaking_tension": 10_000.0} if name == "cable.pretension" else {}
    out = PhysicsOverrides.from_mapping({name: v, **extra})
    assert out.get(name) == v


def test_a_bad_file_is_refused_naming_the_file(tmp_path):
    bad = tmp_path / "robot.toml"
    bad.write_text("[cable]\nbreaking_tension = 5.0\n")
    with pytest.raises(PhysicsError, match=r"robot.toml: cable.breaking_tension = 5.0 N is outside \[100, 10000\] N"):
        PhysicsOverrides.load(bad)
    bad.write_text("[cable\n")
    with pytest.raises(PhysicsError, match="not valid TOML"):
        PhysicsOverrides.load(bad)
    with pytest.raises(PhysicsError, match="cannot read"):
        PhysicsOverrides.load(tmp_path / "missing.toml")


@pytest.mark.parametrize("text, says", [
    ("[cable]\nbreaking_tensoin = 900.0\n", "unknown physical parameter 'cable.breaking_tensoin'"),
    ("[motor.elbow_left]\ncurrent_limit = 0.0\n", "motor.elbow_left.current_limit = 0.0 A is outside [0.01, 100] A"),
    ("[mass]\ntorso = -1\n", "mass.torso = -1 kg is outside"),
    ("[bracing]\nimpact_momentum_mean = \"strong\"\n", "bracing.impact_momentum_mean must be a number"),
    ("[motor.knee]\nfriction = 1.0\n", "unknown physical parameter 'motor.knee.friction'"),
])
def test_sim_refuses_a_bad_physics_file_with_one_line_and_exit_2(tmp_path, text, says):
    f = tmp_path / "robot.toml"
    f.write_text(text)
    # a bus channel nobody serves: the refusal must come before the bus is touched
    proc = subprocess.run([sys.executable, "-m", "firmware_sim", "--bus-interface", "remote",
                           "--bus-channel", "ws://127.0.0.1:9/", "--physics", str(f)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and lines[0].startswith("ersac-hil sim: error: --physics:")
    assert proc.stdout == ""


def test_sim_lists_the_parameter_names():
    proc = subprocess.run([sys.executable, "-m", "firmware_sim", "--physics-names"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0
    assert set(line.split()[0] for line in proc.stdout.splitlines()) == set(PARAMETERS)


# ------------------------------------------------------------------ effects
def test_no_overrides_leave_the_model_as_it_is():
    a, b = Simulator(), Simulator(physics=PhysicsOverrides.from_mapping({}))
    for sim in (a, b):
        sim.reset("lifting", 4)
    ma, mb = a.physics.model, b.physics.model
    for field in ("actuator_gainprm", "actuator_forcerange", "geom_size", "body_mass", "dof_frictionloss"):
        assert np.array_equal(getattr(ma, field), getattr(mb, field)), field
    assert repr(a.truth) == repr(b.truth)


def test_motor_friction_and_mass_overrides_act_on_the_compiled_model():
    o = PhysicsOverrides.from_mapping({
        "motor": {"elbow_left": {"torque_constant": 0.03}, "torso": {"current_limit": 3.0},
                  "shoulder_right": {"friction": 0.7, "torque_constant": 0.02, "current_limit": 5.0}},
        "mass": {"torso": 4.4, "battery": 2.0}})
    base, sim = Simulator(), Simulator(physics=o)
    base.reset("bracing", 1)
    sim.reset("bracing", 1)
    p0, p = read_motor_params(base.physics.model), read_motor_params(sim.physics.model)
    assert p["elbow_left"].kt == 0.03 and p["elbow_left"].current_limit == pytest.approx(p0["elbow_left"].current_limit)
    assert p["torso"].current_limit == pytest.approx(3.0) and p["torso"].kt == p0["torso"].kt
    assert p["shoulder_right"].kt == 0.02 and p["shoulder_right"].current_limit == pytest.approx(5.0)
    m = sim.physics.model
    dof = sim.physics.axes.dof[list(p).index("shoulder_right")]
    assert m.dof_frictionloss[dof] == 0.7
    torso = base.physics.body_id("torso")
    assert m.body_mass[torso] == pytest.approx(4.4)
    assert m.body_mass.sum() == pytest.approx(base.physics.model.body_mass.sum() + 0.4 + 0.6)


def test_overrides_win_over_the_lifting_benchs_own_shoulder_settings_and_set_the_bottle():
    o = PhysicsOverrides.from_mapping({"motor.shoulder_left.current_limit": 4.0, "motor.shoulder_left.friction": 0.2,
                                       "bottle.liquid_mass": 0.8, "bottle.fill_spread": 0.0})
    sim = Simulator(physics=o)
    sim.reset("lifting", 2)
    p = read_motor_params(sim.physics.model)
    assert p["shoulder_left"].current_limit == pytest.approx(4.0)
    assert p["shoulder_right"].current_limit == pytest.approx(2.0)  # the bench's own
    assert sim.truth.liquid_mass == pytest.approx(0.8)  # no spread: exactly the nominal fill


def test_cable_and_impact_overrides_change_the_episodes_draws():
    o = PhysicsOverrides.from_mapping({"cable": {"breaking_tension": 700.0, "strength_cv": 0.0},
                                       "bracing": {"impact_momentum_mean": 30.0, "impact_momentum_std": 0.0}})
    sim = Simulator(physics=o)
    sim.reset("bracing", 5)
    t = sim.truth
    assert t.cable_strength_left == t.cable_strength_right == 700.0
    assert t.impact_momentum == 30.0
    assert Simulator(physics=o, cable=CableSpec(pretension=10.0))._cable.pretension == 10.0
