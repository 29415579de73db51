"""An output directory remembers the code its episodes came from: resuming it with other
simulator/agent code is refused (exit 2, one line), nothing written; the same code resumes."""
from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from ersac_hil.cli import main
from ersac_hil.reproduce.provenance import SOURCES, CodeChanged, fingerprint, guard, mismatch
from ersac_hil.reproduce.plan import QUICK


def test_the_fingerprint_covers_the_simulator_the_agent_and_the_tasks():
    got = fingerprint()
    assert set(got) == set(SOURCES) and all(len(v) == 16 for v in got.values())
    assert got == fingerprint()  # stable
    assert mismatch(None, got) == [] and mismatch(got, got) == []
    assert mismatch({**got, "firmware_sim": "0" * 16}, got) == ["firmware_sim"]


def _plan(out, model) -> str:  # noqa: ANN001
    out.mkdir()
    text = json.dumps({"sizes": asdict(QUICK), "quick": True, "model": model}, indent=1) + "\n"
    (out / "plan.json").write_text(text)
    return text


def test_episodes_of_another_simulator_are_not_mixed_with_new_ones(tmp_path, capsys):
    out = tmp_path / "results"
    text = _plan(out, {**fingerprint(), "firmware_sim": "0123456789abcdef"})
    assert main(["reproduce", "lifting", "--quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "other simulator/agent code (changed: firmware_sim)" in err and "\n" not in err
    assert (out / "plan.json").read_text() == text and sorted(p.name for p in out.iterdir()) == ["plan.json"]


def test_the_guard_stops_a_run_whose_code_changed_under_it():
    now = fingerprint()
    guard(now)()  # unchanged: nothing
    with pytest.raises(CodeChanged, match=r"changed during the run \(ersac_hil.agent\)"):
        guard({**now, "ersac_hil.agent": "0" * 16})()
