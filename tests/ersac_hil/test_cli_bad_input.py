"""Every subcommand answers bad input with one clear line on stderr and exit status 2, before it
starts anything: no traceback, no child process, no file written.

``BAD_INPUT`` holds at least one case per subcommand; a subcommand without one fails
``test_every_subcommand_has_a_bad_input_case`` (add its cases when you add the command).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import ersac_hil
from ersac_hil.canbus import vcan_status
from ersac_hil.cli import build_parser, main

pytestmark = pytest.mark.timeout(120)
NO_ROUTER = "tcp/127.0.0.1:9"  # nothing listens: a command that got this far would hang or fail late
SOCKETCAN_MISSING = not vcan_status("vcan0").available

# (argv, a phrase the one-line answer must contain)
BAD_INPUT: list[tuple[tuple[str, ...], str]] = [
    (("bus-load", "--rate", "0"), "must be positive"),
    (("bus-load", "--bitrate", "fast"), "not an integer"),
    (("bus", "--port", "99999"), "not a TCP port"),
    (("router", "--port", "-1"), "not a TCP port"),
    (("agent", "--robot", "r", "--zenoh", NO_ROUTER, "--bus-interface", "virtual", "--bus-channel", "x",
      "--period-ms", "0"), "must be positive"),
    (("agent", "--robot", "a/b", "--zenoh", NO_ROUTER, "--bus-interface", "virtual", "--bus-channel", "x"),
     "not a valid key chunk"),
    (("agent", "--robot", "r", "--zenoh", NO_ROUTER, "--bus-interface", "remote",
      "--bus-channel", "ws://127.0.0.1:9/"), "no CAN hub answers"),
    (("agent", "--robot", "r", "--zenoh", NO_ROUTER, "--bus-interface", "zenoh", "--bus-channel", "c",
      "--bus-kwargs", "zenoh_config={tmp}/none.json5"), "no such file"),
    (("daemon", "--robot", "r", "--episodes", "0", "--zenoh", NO_ROUTER, "--db", "{tmp}/d.db"), "episodes"),
    (("daemon", "--robot", "r", "--kappa", "nan", "--zenoh", NO_ROUTER, "--db", "{tmp}/d.db"), "finite"),
    (("state", "--timeout", "0", "--zenoh", NO_ROUTER), "must be positive"),
    (("kappa", "set", "nan", "--zenoh", NO_ROUTER), "finite"),
    (("kappa", "set", "--zenoh", NO_ROUTER), "needs a VALUE"),
    (("weights", "set", "damage=-1", "--zenoh", NO_ROUTER), "below the minimum"),
    (("critic", "--grid", "0", "--zenoh", NO_ROUTER), "grid"),
    (("critic", "--zenoh", NO_ROUTER), "--theta"),
    (("select", "--kappa", "1e9", "--zenoh", NO_ROUTER), "above the maximum"),
    (("report", "latest", "--db", "{tmp}/none.db", "--out", "{tmp}/report"), "no store"),
    (("certs", "init", "{tmp}/certs", "--days", "0"), "days must be in"),
    (("certs", "init", "{tmp}/certs", "--router", "nonsense"), "is not of the form"),
    (("reproduce", "bracing", "--seeds", "0", "--out", "{tmp}/results"), "--seeds must be"),
    (("reproduce", "juggling", "--out", "{tmp}/results"), "invalid choice"),
    (("dashboard", "--port", "99999", "--zenoh", NO_ROUTER), "not in 0..65535"),
    (("dashboard", "--robot", "a/b", "--zenoh", NO_ROUTER), "not a valid key chunk"),
    (("demo", "--episodes", "0", "--out", "{tmp}/demo"), "must be a positive integer"),
    (("demo", "--kappa", "nan", "--out", "{tmp}/demo"), "not a finite number"),
    (("demo", "--robot", "a b", "--out", "{tmp}/demo"), "not a valid key chunk"),
]
SIM_BAD_INPUT: list[tuple[tuple[str, ...], str]] = [
    (("--bus-interface", "virtual", "--bus-channel", "x", "--control-period", "0"), "--control-period must be"),
    (("--snapshot", "/nonexistent-dir/frame.png"), "no directory"),
    (("--bus-interface", "virtual", "--bus-channel", "x", "--seed", "-1"), "must not be negative"),
    (("--bus-interface", "remote", "--bus-channel", "ws://127.0.0.1:9/"), "no CAN hub answers"),
    (("--bus-interface", "remote", "--bus-channel", "ws://10.0.0.1:9/"), "loopback"),
    (("--bus-interface", "virtual", "--bus-channel", "x", "--bus-kwargs", "nonsense"), "is not KEY=VALUE"),
    (("--bus-interface", "zenoh", "--bus-channel", "c@tcp/127.0.0.1:9", "--bus-kwargs", "insecure=maybe"),
     "insecure must be true or false"),
]
if SOCKETCAN_MISSING:  # the kernel without SocketCAN: say so, the way vcan_status() does
    reason = vcan_status("vcan0").reason
    BAD_INPUT.append((("agent", "--robot", "r", "--zenoh", NO_ROUTER, "--bus-interface", "socketcan",
                       "--bus-channel", "vcan0"), reason))
    SIM_BAD_INPUT.append((("--bus-interface", "socketcan", "--bus-channel", "vcan0"), reason))


def _subcommands() -> set[str]:
    sub = next(a for a in build_parser()._actions if a.choices and isinstance(a.choices, dict))
    return set(sub.choices)


def test_every_subcommand_has_a_bad_input_case():
    covered = {argv[0] for argv, _ in BAD_INPUT} | {"sim"}
    assert _subcommands() <= covered, f"no bad-input case for {sorted(_subcommands() - covered)}"


def _one_line(err: str, needle: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and needle in lines[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize("argv, needle", BAD_INPUT, ids=lambda v: " ".join(v) if isinstance(v, tuple) else "")
def test_bad_input_is_one_line_and_exit_2(argv, needle, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    out, err = capsys.readouterr()
    assert code == 2, out + err
    _one_line(err, needle)
    assert list(tmp_path.iterdir()) == [], "bad input must change nothing"


@pytest.mark.parametrize("argv, needle", SIM_BAD_INPUT, ids=lambda v: " ".join(v) if isinstance(v, tuple) else "")
def test_sim_bad_input_is_one_line_and_exit_2(argv, needle):
    """``ersac-hil sim`` runs the simulator's own entry point: a process of its own."""
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "sim", *argv], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "simulator:" not in proc.stdout  # refused before a node came up
    _one_line(proc.stderr, needle)


def test_version():
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "--version"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == f"ersac-hil {ersac_hil.__version__}"


def test_version_is_the_distribution_version():
    from importlib.metadata import version
    assert ersac_hil.__version__ == version("ersac-hil")
    assert Path(ersac_hil.__file__).parent.name == "ersac_hil"
