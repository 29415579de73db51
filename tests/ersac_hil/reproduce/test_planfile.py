"""``plan.json``: each experiment keeps the sizes it was made with (run one at a time into one
directory, then ``all``), real conflicts are refused in one line with nothing written, and a
learning run made by other learner code is refused while the trials stay reusable."""
from __future__ import annotations

import contextlib
import json
from dataclasses import asdict, fields, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.cli import main
from ersac_hil.reproduce.plan import FULL, QUICK, Sizes
from ersac_hil.reproduce.planfile import FIELDS, INTERLEAVE, SIZE_FIELDS, PlanConflict, resolve, runs_of

MODEL = {"firmware_sim": "a" * 16, "ersac_hil.agent": "b" * 16, "protocol.zenoh": "c" * 16}
LEARN = {"ersac_hil.learner": "d" * 16, "ersac_hil.critic": "e" * 16, "ersac_hil.daemon.engine": "f" * 16}
ALL = ("bracing", "lifting", "contexts")


def _run(record, experiments, sizes=FULL, explicit=False, learning=LEARN, existing=()):  # noqa: ANN001, ANN202
    """``explicit``: True for a size option (--seeds, --quick), else the fields set explicitly."""
    fields_ = SIZE_FIELDS if explicit is True else (explicit or ())
    return resolve(record, experiments, sizes, fields_, MODEL, learning, set(existing))


_no_exit = contextlib.nullcontext


def test_every_size_belongs_to_an_experiment():
    assert {f for fs in FIELDS.values() for f in fs} == {f.name for f in fields(Sizes)}


def test_experiments_run_one_at_a_time_then_all_keep_their_sizes():
    first = _run(None, ("bracing",), FULL.with_seeds(3), explicit=True)
    assert first.sizes.bracing_seeds == 3 and set(first.record["experiments"]) == {"bracing"}
    then = _run(first.record, ALL)  # `reproduce all` without options
    assert then.sizes.bracing_seeds == 3 and then.sizes.lifting_seeds == FULL.lifting_seeds
    assert then.record["experiments"]["bracing"] == first.record["experiments"]["bracing"]
    assert not then.quick and _run(then.record, ALL).record == then.record


def test_an_explicit_size_against_a_recorded_one_is_refused():
    record = _run(None, ("bracing",), FULL.with_seeds(3), explicit=True).record
    with pytest.raises(PlanConflict, match=r"bracing has bracing_seeds 3 \(asked 5\)"):
        _run(record, ALL, FULL.with_seeds(5), explicit=True)
    # lifting was never run: its seeds are free; the same bracing seeds agree
    assert _run(record, ("lifting",), FULL.with_seeds(5), explicit=True).sizes.lifting_seeds == 5
    assert _run(record, ALL, FULL.with_seeds(3), explicit=True).sizes.lifting_seeds == 3


def test_contexts_continue_the_recorded_lifting_run():
    record = _run(None, ("lifting",), QUICK, explicit=True).record
    taken = _run(record, ("contexts",))
    assert (taken.sizes.lifting_episodes, taken.sizes.test_trials) == (QUICK.lifting_episodes, QUICK.test_trials)
    assert taken.sizes.context_episodes == FULL.context_episodes and not taken.quick
    with pytest.raises(PlanConflict, match="lifting has lifting_episodes 12 \\(asked 30\\)"):
        _run(record, ("contexts",), FULL, explicit=True)


def test_a_directory_with_one_size_set_is_read_as_every_experiments():
    legacy = {"sizes": json.loads(json.dumps(asdict(QUICK))), "quick": True, "model": MODEL}
    got = _run(legacy, ALL)
    assert got.sizes == QUICK and got.quick
    with pytest.raises(PlanConflict, match="other sizes"):
        _run(legacy, ("lifting",), FULL, explicit=True)


def test_other_episode_code_is_refused():
    record = _run(None, ALL).record
    with pytest.raises(PlanConflict, match=r"other simulator/agent code \(changed: firmware_sim\)"):
        resolve(record, ALL, FULL, (), {**MODEL, "firmware_sim": "0" * 16}, LEARN, set())


def test_learning_runs_of_other_learner_code_are_refused_and_the_rest_reused():
    record = _run(None, ALL, QUICK, explicit=True).record
    names = {spec.name for e in ALL for spec in runs_of(e, QUICK)}
    assert set(record["runs"]) == names and all(v == LEARN for v in record["runs"].values())
    critic = {**LEARN, "ersac_hil.critic": "0" * 16}
    with pytest.raises(PlanConflict, match=r"learner code \(bracing-k2-s1; changed: ersac_hil.critic\)"):
        _run(record, ("bracing",), learning=critic, existing={"bracing-k2-s1", "lifting-k0-s1"})
    # no stored learning run of bracing (removed): allowed, and its runs are recorded anew
    again = _run(record, ("bracing",), learning=critic, existing={"lifting-k0-s1"})
    assert again.record["runs"]["bracing-k2-s1"] == critic and again.record["runs"]["lifting-k0-s1"] == LEARN
    with pytest.raises(PlanConflict, match="lifting-k0-s1"):  # contexts continue lifting's run
        _run(again.record, ("contexts",), learning=critic, existing={"lifting-k0-s1"})
    assert _run(record, ("bracing",), existing={"bracing-k2-s1"}).record["runs"] == record["runs"]


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 20), st.integers(1, 20), st.sampled_from(ALL), st.sampled_from(ALL))
def test_explicit_seeds_conflict_only_with_the_same_experiments_seeds(a, b, first, second):
    """--seeds sets bracing's and lifting's run seeds; contexts have none."""
    record = _run(None, (first,), FULL.with_seeds(a), explicit=True).record
    conflict = a != b and first == second != "contexts"
    try:
        got = _run(record, (second,), FULL.with_seeds(b), explicit=True)
    except PlanConflict as exc:
        assert conflict, exc
    else:
        assert not conflict
        if first != second:
            assert got.record["experiments"][first] == record["experiments"][first]
            assert got.sizes == FULL.with_seeds(b)


def test_the_cli_refuses_a_conflict_in_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "results"
    out.mkdir()
    record = _run(None, ("bracing",), FULL.with_seeds(3), explicit=True).record
    text = json.dumps({**record, "model": None}, indent=1) + "\n"
    (out / "plan.json").write_text(text)
    assert main(["reproduce", "all", "--seeds", "4", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "bracing has bracing_seeds 3 (asked 4)" in err and "\n" not in err
    assert (out / "plan.json").read_text() == text and sorted(p.name for p in out.iterdir()) == ["plan.json"]


def test_the_lifting_interleave_option_is_recorded_and_taken_over():
    asked = replace(FULL, lifting_interleave_every=5)
    first = _run(None, ("lifting",), asked, explicit={INTERLEAVE})
    assert first.record["experiments"]["lifting"][INTERLEAVE] == 5
    assert all(spec.extra == ("--interleave-every", "5") for spec in runs_of("lifting", first.sizes))
    then = _run(first.record, ALL)  # `reproduce all`: lifting's and the contexts' option taken over
    assert then.sizes.lifting_interleave_every == 5 and then.sizes.bracing_seeds == FULL.bracing_seeds
    assert all(spec.extra == ("--interleave-every", "5") for spec in runs_of("contexts", then.sizes))
    with pytest.raises(PlanConflict, match=r"lifting has lifting_interleave_every 5 \(asked 0\)"):
        _run(then.record, ("contexts",), FULL, explicit={INTERLEAVE})
    # a size option does not re-assert the learner option; the paper's runs carry no flag
    assert _run(then.record, ("lifting",), FULL, explicit=True).sizes.lifting_interleave_every == 5
    assert all(spec.extra == () for spec in runs_of("lifting", FULL))


def test_an_experiment_recorded_before_the_option_reads_as_the_papers_algorithm():
    record = _run(None, ALL, QUICK, explicit=True).record
    for exp in ("lifting", "contexts"):
        del record["experiments"][exp][INTERLEAVE]
    assert _run(record, ALL).sizes.lifting_interleave_every == 0
    with pytest.raises(PlanConflict, match=r"lifting_interleave_every 0 \(asked 3\)"):
        _run(record, ("lifting",), replace(QUICK, lifting_interleave_every=3), explicit={INTERLEAVE})


@pytest.mark.parametrize("bad", ["-1", "1001", "x"])
def test_the_cli_refuses_a_bad_lifting_interleave_and_writes_nothing(tmp_path, capsys, bad):
    out = tmp_path / "results"
    with pytest.raises(SystemExit) if bad == "x" else _no_exit():
        assert main(["reproduce", "lifting", "--lifting-interleave", bad, "--out", str(out)]) == 2
    assert "--lifting-interleave" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
