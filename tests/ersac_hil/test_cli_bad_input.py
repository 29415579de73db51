"""Every subcommand answers bad input with one clear line on stderr and exit status 2, before it
starts anything: no traceback, no child process, no file written.

The test is parametrised over the subcommands the parser has (found by walking it, so a new
subcommand is a new test case), and runs every case of ``BAD_INPUT`` for it plus an unknown
option; a subcommand without a case of its own in ``BAD_INPUT`` fails (add its cases when you
add the command). ``sim`` execs ``python -m firmware_sim``: its cases run as processes.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

import ersac_hil
from ersac_hil.canbus import vcan_status
from ersac_hil.cli import build_parser, main

pytestmark = pytest.mark.timeout(180)
NO_ROUTER = "tcp/127.0.0.1:9"  # nothing listens: a command that got this far would hang or fail late
Z = ("--zenoh", NO_ROUTER)
SOCKETCAN = vcan_status("vcan0")
UNKNOWN_OPTION = (("--no-such-option",), "error:")
"""Every subcommand gets this case too."""

# subcommand -> [(its arguments, a phrase the one-line answer must contain)]; {tmp}: a directory
# that holds only {given}: a bracing store of robot r (bracing.db), an empty file (empty.db), a
# text file (file) and a json5 file with a syntax error (bad.json5), which every refusal must leave
# byte for byte as they were
BAD_INPUT: dict[str, list[tuple[tuple[str, ...], str]]] = {
    "bus-load": [(("--rate", "0"), "must be positive"), (("--bitrate", "fast"), "not an integer"),
                 (("--description", "ubot9"), "no shipped robot description"),
                 (("--bitrate", "125000"), "more than the bus carries")],
    "bus": [(("--port", "99999"), "not a TCP port")],
    "router": [(("--port", "-1"), "not a TCP port")],
    "agent": [
        (("--robot", "r", *Z, "--bus-interface", "virtual", "--bus-channel", "x", "--period-ms", "0"),
         "must be positive"),
        (("--robot", "a/b", *Z, "--bus-interface", "virtual", "--bus-channel", "x"), "not a valid key chunk"),
        (("--robot", "r", *Z, "--bus-interface", "remote", "--bus-channel", "ws://127.0.0.1:9/"),
         "no CAN hub answers"),
        (("--robot", "r", *Z), "no CAN interface/channel given"),
        (("--robot", "r", *Z, "--bus-interface", "zenoh", "--bus-channel", "c",
          "--bus-kwargs", "zenoh_config={tmp}/none.json5"), "no such file"),
        (("--robot", "r", *Z, "--bus-interface", "virtual", "--bus-channel", "x", "--description", "{tmp}/none.toml"),
         "none.toml: cannot read it"),
        (("--robot", "r", *Z, "--bus-interface", "socketcan", "--bus-channel", "can0", "--lockstep"),
         "lock-step refused on socketcan:can0: socketcan can0 is a physical CAN bus"),
        (("--robot", "r", *Z, "--bus-interface", "virtual", "--bus-channel", "x", "--lockstep",
          "--realtime"), "not allowed with argument"),
        (("--robot", "r", *Z, "--bus-interface", "virtual", "--bus-channel", "x", "--keep-awake"),
         "--keep-awake is for real time"),
    ],
    "commission": [(("--description", "{tmp}/none.toml", "--bus-interface", "virtual", "--bus-channel", "x"),
                    "--description"),
                   (("--move", "tail", "--bus-interface", "virtual", "--bus-channel", "x"), "no such axis"),
                   (("--bus-interface", "remote", "--bus-channel", "ws://127.0.0.1:9/"), "no CAN hub answers")],
    "estop": [(("--robot", "a/b", *Z), "not a valid key chunk"), (("--timeout", "0", *Z), "must be positive")],
    "go": [(("--robot", "a/b", *Z), "not a valid key chunk"), (("--timeout", "-1", *Z), "must be positive")],
    "daemon": [
        (("--robot", "r", "--episodes", "0", *Z, "--db", "{tmp}/d.db"), "episodes"),
        (("--robot", "r", "--kappa", "nan", *Z, "--db", "{tmp}/d.db"), "finite"),
        (("--robot", "r", "--resume", "20260101T000000-abcdef", *Z, "--db", "{tmp}/d.db"), "no store"),
        (("--robot", "r", *Z, "--db", "{tmp}"), "is a directory"),
        (("--robot", "r", "--zenoh", "nonsense", "--db", "{tmp}/d.db"), "invalid zenoh endpoints"),
        (("--robot", "r", "--task", "lifting", *Z, "--db", "{given}/bracing.db"), "a store of bracing on r"),
        (("--robot", "r2", *Z, "--db", "{given}/bracing.db"), "not of bracing on r2"),
        (("--robot", "r", "--resume", "20260101T000000-abcdef", *Z, "--db", "{given}/bracing.db"), "no run"),
        (("--robot", "r", "--kappa", "2", *Z, "--db", "{given}/bracing.db"), "was started with kappa"),
        (("--robot", "r", *Z, "--db", "{given}/empty.db"), "not an ersac-hil store (an empty file)"),
        (("--robot", "r", *Z, "--db", "{given}/file"), "not an ersac-hil store"),
    ],
    "state": [(("--timeout", "0", *Z), "must be positive"),
              (("--zenoh", "not an endpoint"), "Endpoints must be of the form <protocol>/<address>"),
              (("--zenoh-config", "{given}/bad.json5"), "json5 syntax error: the parser stops at line 1")],
    "kappa": [(("set", "nan", *Z), "finite"), (("set", *Z), "needs a VALUE")],
    "weights": [(("set", "damage=-1", *Z), "below the minimum"), (("set", "colour=1", *Z), "not a cost term")],
    "critic": [(("--grid", "0", *Z), "grid"), (Z, "--theta")],
    "select": [(("--kappa", "1e9", *Z), "above the maximum")],
    "report": [(("latest", "--db", "{tmp}/none.db", "--out", "{tmp}/report"), "no store"),
               (("latest", "--out", "/proc/report"), "cannot write"),
               (("20260101T000000-abcdef", "--db", "{given}/bracing.db", "--out", "{tmp}/report"), "no run"),
               (("latest", "--db", "{given}/empty.db", "--out", "{tmp}/report"), "not an ersac-hil store")],
    "certs init": [(("{tmp}/certs", "--days", "0"), "days must be in"),
                   (("{given}/file",), "not a directory"),
                   (("{tmp}/certs", "--router", "nonsense"), "is not of the form")],
    "reproduce": [(("bracing", "--seeds", "0", "--out", "{tmp}/results"), "--seeds must be"),
                  (("juggling", "--out", "{tmp}/results"), "invalid choice"),
                  (("bracing", "--out", "/proc/results"), "cannot write"),
                  (("bracing", "--quick", "--pairs", "1000", "--out", "{tmp}/results"), "--oversubscribe starts")],
    "dashboard": [(("--port", "99999", *Z), "not in 0..65535"), (("--robot", "a/b", *Z), "not a valid key chunk")],
    "demo": [
        (("--episodes", "0", "--out", "{tmp}/demo"), "must be a positive integer"),
        (("--kappa", "nan", "--out", "{tmp}/demo"), "not a finite number"),
        (("--robot", "a b", "--out", "{tmp}/demo"), "not a valid key chunk"),
        (("--dashboard-port", "99999", "--out", "{tmp}/demo"), "not a TCP port"),
        (("--out", "/proc/demo"), "cannot write"),
        (("--description", "{tmp}/none.toml", "--out", "{tmp}/demo"), "none.toml: cannot read it"),
        (("--fleet", "1000", "--out", "{tmp}/demo"), "--oversubscribe starts"),
    ],
    "sim": [
        (("--bus-interface", "virtual", "--bus-channel", "x", "--control-period", "0"), "--control-period must be"),
        (("--snapshot", "/nonexistent-dir/frame.png"), "no directory"),
        (("--snapshot", "{tmp}/frame.png", "--scenario", "juggling"), "--scenario 'juggling' is not one of"),
        (("--bus-interface", "virtual", "--bus-channel", "x", "--seed", "-1"), "must not be negative"),
        (("--bus-interface", "remote", "--bus-channel", "ws://127.0.0.1:9/"), "no CAN hub answers"),
        (("--bus-interface", "remote", "--bus-channel", "ws://10.0.0.1:9/"), "loopback"),
        ((), "no CAN interface/channel given"),
        (("--bus-interface", "virtual", "--bus-channel", "x", "--bus-kwargs", "nonsense"), "is not KEY=VALUE"),
        (("--bus-interface", "zenoh", "--bus-channel", "c@tcp/127.0.0.1:9", "--bus-kwargs", "insecure=maybe"),
         "insecure must be true or false"),
    ],
}
if not SOCKETCAN.available:  # the kernel without SocketCAN: say so, the way vcan_status() does
    BAD_INPUT["agent"].append((("--robot", "r", *Z, "--bus-interface", "socketcan", "--bus-channel", "vcan0"),
                               SOCKETCAN.reason))
    BAD_INPUT["sim"].append((("--bus-interface", "socketcan", "--bus-channel", "vcan0"), SOCKETCAN.reason))


def _commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> list[str]:
    """Every runnable subcommand of ``parser`` ("certs init": a subcommand's subcommand)."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                nested = _commands(sub, (*prefix, name))
                found += nested or [" ".join((*prefix, name))]
    return found


COMMANDS = _commands(build_parser())


def _children() -> set[int]:
    """Child processes of every thread of this process (a thread that ends while it is listed
    has none left to count)."""
    pids: set[int] = set()
    for task in Path("/proc/self/task").iterdir():
        try:
            pids.update(int(pid) for pid in (task / "children").read_text().split())
        except (FileNotFoundError, ProcessLookupError):
            continue
    return pids


def _check(code: int | None, err: str, needle: str) -> str | None:
    """What is wrong with one answer (``None``: a usage error of one line naming ``needle``)."""
    lines = [line for line in err.splitlines() if line.strip()]
    if code != 2 or len(lines) != 1 or "Traceback" in err or needle not in lines[0]:
        return f"exit {code}, stderr {err!r} (wanted one line with {needle!r})"
    return None


def _run_in_process(argv: list[str], capsys) -> tuple[int | None, str]:  # noqa: ANN001
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    return code, capsys.readouterr().err


def _run_sim(argv: list[str]) -> tuple[int | None, str]:
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", *argv], capture_output=True, text=True,
                          timeout=60)
    if "simulator:" in proc.stdout:  # a node came up: too late for a usage error
        return None, proc.stderr
    return proc.returncode, proc.stderr


def _given(directory: Path) -> Path:
    """The files the cases refer to as {given}: a closed bracing store of robot r with one
    running run (kappa 0), an empty file, a text file, a json5 file with a syntax error."""
    from ersac_hil.daemon.config import DaemonConfig
    from ersac_hil.daemon.runs import open_run
    from ersac_hil.daemon.store import Store
    directory.mkdir()
    with Store(directory / "bracing.db") as store:
        open_run(store, DaemonConfig(robot="r", task="bracing", seed=1, db=directory / "bracing.db"))
    (directory / "empty.db").touch()
    (directory / "file").write_text("not a store\n")
    (directory / "bad.json5").write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:9"] },\n bad }\n')
    return directory


def _tree(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` with its bytes (``None``: a directory)."""
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("command", COMMANDS)
def test_bad_input_is_one_line_and_exit_2(command, tmp_path, capsys):
    cases = BAD_INPUT.get(command, [])
    assert cases, f"no bad-input case for {command!r}: add its cases to BAD_INPUT"
    given = _given(tmp_path / "given")
    before = _tree(tmp_path)
    children = _children()
    wrong = []
    for args, needle in [*cases, UNKNOWN_OPTION]:
        argv = [*command.split(), *(a.replace("{given}", str(given)).replace("{tmp}", str(tmp_path)) for a in args)]
        code, err = _run_sim(argv) if command == "sim" else _run_in_process(argv, capsys)
        problem = _check(code, err, needle)
        if problem:
            wrong.append(f"ersac-hil {' '.join(argv)}: {problem}")
        after = _tree(tmp_path)
        if after != before:
            changed = sorted(k for k in after.keys() | before.keys() if after.get(k, 0) != before.get(k, 0))
            wrong.append(f"ersac-hil {' '.join(argv)} wrote or changed {changed}")
        assert _children() <= children, f"ersac-hil {' '.join(argv)} left a child process"
    assert not wrong, "\n".join(wrong)


def test_a_daemon_without_a_session_writes_nothing(tmp_path, capsys):
    """No router: the daemon fails to open its session (exit 1, one line) before it creates the
    store, its directories or a run - nor does it touch a store that is there."""
    given = _given(tmp_path / "given")
    quick = tmp_path / "quick.json5"  # the file's connect timeout, not the daemon's 10 s
    quick.write_text("{ connect: { timeout_ms: 500 } }")
    before = _tree(tmp_path)
    for db in (tmp_path / "no" / "such" / "dir" / "x.db", given / "bracing.db"):
        code, err = _run_in_process(["daemon", "--robot", "r", *Z, "--zenoh-config", str(quick), "--db", str(db)],
                                    capsys)
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 1 and len(lines) == 1 and "zenoh session" in lines[0], err
        assert _tree(tmp_path) == before


def test_version():
    proc = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "--version"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == f"ersac-hil {ersac_hil.__version__}"


def test_version_is_the_distribution_version():
    from importlib.metadata import version
    assert ersac_hil.__version__ == version("ersac-hil")
    assert Path(ersac_hil.__file__).parent.name == "ersac_hil"
