"""``ersac-hil reproduce contexts --quick`` end to end through every real process. ``reproduce
bracing --quick`` (interrupted, resumed, reported) is tested in test_fleet_reproduce.py, where
its one run is also the reference of the run on pairs elsewhere."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.daemon.store import Store
from helpers.processes import group_killed_on_exit, running_with

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}

pytestmark = pytest.mark.slow


def test_quick_contexts_with_interleaved_lifting_runs_carry_the_option_to_every_daemon(tmp_path):
    """``--lifting-interleave`` reaches the daemons of the lifting run and of the context runs
    that continue it (stored with each run), and the plan records it."""
    out = tmp_path / "results"
    proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "reproduce", "contexts", "--quick",
                             "--lifting-interleave", "2", "--out", str(out)], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    with group_killed_on_exit(proc):
        text, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, text
    plan = json.loads((out / "plan.json").read_text())
    assert plan["experiments"]["contexts"]["lifting_interleave_every"] == 2
    dbs = sorted((out / "runs").glob("*.db"))
    assert [p.stem for p in dbs] == ["context-energy_averse", "context-translation_averse", "lifting-k0-s1"]
    for db in dbs:
        with Store(db, readonly=True) as store:
            (run,) = store.runs()
            assert run.settings["interleave_every"] == 2 and run.status == "finished", db
    assert not running_with(out)
