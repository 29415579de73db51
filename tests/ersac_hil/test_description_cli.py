"""``--description`` on every command that serves a robot: a bad description is refused with
the loader's one line naming the field, exit status 2, before anything starts."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from protocol.robot.load import SHIPPED_DIR

pytestmark = pytest.mark.timeout(180)
NO_ROUTER = ("--zenoh", "tcp/127.0.0.1:9")
BUS = ("--bus-interface", "virtual", "--bus-channel", "description-cli")


def _bad_description(tmp_path: Path) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text((SHIPPED_DIR / "ubot5.toml").read_text().replace("gear = 120.0", "gear = -3", 1))
    return path


@pytest.mark.parametrize("command", [
    ("bus-load",),
    ("sim", *BUS),
    ("agent", "--robot", "r", *BUS, *NO_ROUTER),
    ("demo", "--out", "{tmp}/demo"),
])
def test_a_bad_description_is_refused_before_anything_starts(command, tmp_path):
    bad = _bad_description(tmp_path)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in command]
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", *argv, "--description", str(bad)],
                          capture_output=True, text=True, timeout=120)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert f"{bad}: axes.elbow_left.gear: must be > 0, got -3" in lines[0]
    assert proc.stdout == ""  # no simulator, agent or stack came up
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]  # nothing written


def test_drives_and_description_are_one_choice():
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "sim", *BUS, "--drives", "cia402",
                           "--description", "ubot5"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert "argument --description: not allowed with argument --drives" in proc.stderr


def test_a_description_file_runs_the_simulator(tmp_path):
    """A copy of the default description as a file: the simulator comes up with its nodes."""
    mine = tmp_path / "mine.toml"
    mine.write_text((SHIPPED_DIR / "ubot5.toml").read_text().replace('name = "ubot5"', 'name = "mine"'))
    proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "sim", *BUS, "--description", str(mine)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("simulator: 6 nodes on virtual:"), line
        assert "200 Hz" in line and line.rstrip().endswith("robot mine"), line
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        proc.stdout.close()
        proc.stderr.close()
