"""``ersac-hil reproduce bracing --quick`` end to end through every real process: interrupted
with Ctrl-C (no child left, exit 130), run again (it resumes: the stored episodes are not run
again), then the results files exist and parse, and the figures are PNGs."""
from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.daemon.store import Store
from helpers.processes import children, gone, group_killed_on_exit, lines_until, running_with

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
PNG = b"\x89PNG\r\n\x1a\n"

pytestmark = pytest.mark.slow


def _reproduce(out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "reproduce", "bracing", "--quick",
                             "--out", str(out)], cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


@pytest.mark.timeout(900)  # --quick is 55 episodes: minutes on a loaded 2-core machine
def test_quick_bracing_is_interrupted_resumed_and_reported(tmp_path):
    out = tmp_path / "results"
    with group_killed_on_exit(_reproduce(out)) as proc:
        lines = lines_until(proc, r"\] ([3-9]|\d\d)/\d+ episodes", 180)  # a few episodes are stored
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
    first = "".join(lines) + rest
    assert proc.returncode == 130 and "interrupted" in first, first
    assert all(gone(pid) for pid in children(first).values()) and not running_with(out), first
    stored = int(re.findall(r"\] (\d+)/\d+ episodes", first)[-1])

    with group_killed_on_exit(_reproduce(out)) as proc:
        second, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, second
    match = re.search(r"(\d+) episodes to have \((\d+) already stored\)", second)
    assert match and int(match.group(2)) >= stored > 0, second
    assert not running_with(out)

    results = json.loads((out / "results.json").read_text())
    bracing = results["bracing"]
    assert len(bracing["final_theta"]["kappa_2"]) == len(bracing["final_theta"]["kappa_0"]) == 2
    assert math.isfinite(bracing["paired"]["wilcoxon_p_one_sided"])  # two paired differences
    assert bracing["landscape"]["episodes_per_theta"] == 2 and len(bracing["landscape"]["rows"]) == 2
    assert {t["target"].split(":")[0] for t in results["targets"]} >= {"landscape", "bracing"}
    assert "| run seed |" in (out / "results.md").read_text()
    for name in ("bracing_landscape.png", "bracing_runs.png", "fig1_critic.png", "fig2_critic.png"):
        assert (out / name).read_bytes()[:8] == PNG, name
    for kappa, seed in ((k, s) for k in ("2", "0") for s in (1, 2)):
        with Store(out / "runs" / f"bracing-k{kappa}-s{seed}.db", readonly=True) as store:
            (run,) = store.runs()
            assert run.status == "finished" and len(store.ok_episodes(run.run_id)) == 12
            assert run.settings["eta"] == 0.7 and run.settings["sigma"] == [0.05]  # the paper's
            moves = [u for u in store.updates(run.run_id) if u.theta_after != u.theta_before]
            assert moves, "the learner never moved theta: the quick run is inside its warm-up"


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
