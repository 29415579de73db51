"""Daemon configuration: the interleaved-search option is a learner setting of the run (stored,
kept on resume, a different explicit value refused, legacy runs read as off) and reaches the
learner; bad values are refused before anything starts."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.daemon.config import LEARNER_FIELDS, LEGACY_SETTINGS, ConfigError, DaemonConfig, load_toml, merge
from ersac_hil.daemon.engine import Engine
from ersac_hil.daemon.runs import open_run
from ersac_hil.daemon.store import Store

ROOT = Path(__file__).resolve().parents[3]


def test_every_learner_field_has_a_legacy_value_or_was_there_from_the_start():
    assert set(LEGACY_SETTINGS) <= set(LEARNER_FIELDS)
    # a run stored before learners had names was made with the guarded rule, which lifting keeps
    lifting = DaemonConfig(robot="r", task="lifting")
    assert LEGACY_SETTINGS["interleave_every"] == 0 == lifting.interleave_every
    assert LEGACY_SETTINGS["learner"] == "guarded" == lifting.learner


def test_the_learner_preset_sets_the_defaults_and_an_explicit_interleave_wins():
    bracing = DaemonConfig(robot="r")
    assert (bracing.learner, bracing.interleave_every) == ("select", 1)
    assert DaemonConfig(robot="r", learner="paper").interleave_every == 0
    assert DaemonConfig(robot="r", interleave_every=5).interleave_every == 5
    paper = {**DaemonConfig(robot="r", learner="paper", seed=1).learner_settings(), "seed": 1}
    assert Engine.create("bracing", paper)._learner.get_state()["max_step"] is None
    guarded = {**DaemonConfig(robot="r", learner="guarded", seed=1).learner_settings(), "seed": 1}
    assert Engine.create("bracing", guarded)._learner.get_state()["max_step"] == 3.0
    # the trust-region learner: its greedy rule reaches the learner and its state
    trust = {**DaemonConfig(robot="r", learner="trust", seed=1).learner_settings(), "seed": 1}
    assert trust["interleave_every"] == 1
    state = Engine.create("bracing", trust)._learner.get_state()
    assert state["greedy"] == {"z": 0.0, "radius": 2.0, "min_move": 0.0, "around": "theta"}
    assert Engine.create("bracing", guarded)._learner.get_state()["greedy"]["around"] == "data"


@pytest.mark.parametrize("bad", ["Paper", "ersac", ""])
def test_an_unknown_learner_is_refused_naming_the_known_ones(bad):
    with pytest.raises(ConfigError, match="unknown learner .*known: paper, guarded, select"):
        merge({}, {"robot": "r", "learner": bad})


@settings(max_examples=25, deadline=None)
@given(k=st.integers(0, 1000))
def test_interleave_every_is_stored_and_reaches_the_learner(k):
    config = DaemonConfig(robot="r", task="lifting", interleave_every=k, seed=3)
    stored = {**config.learner_settings(), "seed": 3}
    assert stored["interleave_every"] == k
    assert Engine.create("lifting", stored)._learner.get_state()["interleave_every"] == k


@pytest.mark.parametrize("bad", [-1, 1001, 1.5, True, "5"])
def test_a_bad_interleave_every_is_refused(bad):
    with pytest.raises(ConfigError, match="interleave_every"):
        merge({}, {"robot": "r", "interleave_every": bad})


def test_interleave_every_from_a_toml_file(tmp_path):
    f = tmp_path / "d.toml"
    f.write_text('robot = "u"\ntask = "lifting"\ninterleave_every = 5\n')
    assert merge(load_toml(f), {}).interleave_every == 5


def test_a_resumed_run_keeps_its_interleave_every_and_refuses_another(tmp_path):
    with Store(tmp_path / "i.db") as store:
        run, config, resumed = open_run(store, merge({}, {"robot": "r", "interleave_every": 5, "seed": 1,
                                                          "resume": "new"}))
        assert run.settings["interleave_every"] == 5 and not resumed
        again, config, resumed = open_run(store, DaemonConfig(robot="r"))
        assert resumed and again.run_id == run.run_id and config.interleave_every == 5
        assert open_run(store, merge({}, {"robot": "r", "interleave_every": 5}))[2]
        with pytest.raises(ConfigError, match="interleave_every"):
            open_run(store, merge({}, {"robot": "r", "interleave_every": 0}))


def test_a_run_stored_before_the_option_existed_resumes_with_it_off(tmp_path):
    with Store(tmp_path / "old.db") as store:
        settings = {**DaemonConfig(robot="r", seed=2).learner_settings(), "seed": 2}
        del settings["interleave_every"]
        store.create_run("0123456789abcdef", "r", "bracing", 2, settings)
        run, config, resumed = open_run(store, DaemonConfig(robot="r"))
        assert resumed and config.interleave_every == 0
        with pytest.raises(ConfigError, match="interleave_every"):
            open_run(store, merge({}, {"robot": "r", "interleave_every": 3}))
        assert open_run(store, merge({}, {"robot": "r", "interleave_every": 0}))[2]


def test_a_bad_interleave_flag_exits_2_and_creates_nothing(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    done = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "daemon", "--robot", "u", "--interleave-every",
                           "-2", "--db", str(tmp_path / "x.db")], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "interleave_every" in done.stderr, done.stderr
    assert not (tmp_path / "x.db").exists()
