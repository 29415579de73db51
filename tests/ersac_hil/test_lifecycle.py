"""The lifecycle of a command's processes, with real processes and real signals: the first
SIGINT/SIGTERM asks for a graceful stop, a second kills the whole tree at once, and a child
dies with the process that started it whatever it does with SIGTERM."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ersac_hil.lifecycle import descendants, kill_tree
from helpers.processes import gone
from helpers.waiting import wait_until

ROOT = Path(__file__).resolve().parents[2]
STUBBORN = ("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); time.sleep(600)")
"""A child that ignores SIGINT and SIGTERM (like one stuck in its shutdown)."""


def _python(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _line(proc: subprocess.Popen) -> str:
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line, f"exited with {proc.wait()} before its line"
    return line.strip()


@pytest.fixture
def procs():
    started: list[subprocess.Popen] = []
    yield started
    for proc in started:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


HANGS = f"""
    import subprocess, sys, threading
    from ersac_hil.lifecycle import until_signal

    def main(stop: threading.Event) -> int:
        child = subprocess.Popen([sys.executable, "-c", {STUBBORN!r}], stdout=subprocess.PIPE, text=True,
                                 start_new_session=True)
        child.stdout.readline()
        print("child", child.pid, flush=True)
        stop.wait()
        print("stopping", flush=True)
        threading.Event().wait()  # a stop that never ends
        return 0

    sys.exit(until_signal(main))
"""


@pytest.mark.parametrize("first, second", [(signal.SIGINT, signal.SIGINT), (signal.SIGTERM, signal.SIGINT)])
def test_a_second_signal_kills_the_tree_and_exits_at_once(procs, first, second):
    proc = _python(HANGS)
    procs.append(proc)
    child = int(_line(proc).split()[1])
    proc.send_signal(first)
    assert _line(proc) == "stopping"
    assert proc.poll() is None and not gone(child)  # the first signal only asks
    proc.send_signal(second)
    assert proc.wait(60) == 128 + first
    assert "second signal: 1 child process(es) killed" in proc.stdout.read()
    wait_until(lambda: gone(child), what="the child in its own process group killed")


def test_one_signal_lets_main_finish_and_returns_128_plus_n(procs):
    proc = _python("""
        import sys, threading
        from ersac_hil.lifecycle import until_signal

        def main(stop: threading.Event) -> int:
            print("up", flush=True)
            stop.wait()
            print("cleaned up", flush=True)
            return 0

        sys.exit(until_signal(main))
    """)
    procs.append(proc)
    assert _line(proc) == "up"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) == 128 + signal.SIGTERM
    assert proc.stdout.read().strip() == "cleaned up"


SWALLOWED = """
    import os, signal, sys, threading, time
    from ersac_hil.lifecycle import note_early_interrupts, until_signal

    note_early_interrupts()

    class Finaliser:
        def __del__(self):  # a SIGINT here is "Exception ignored": Python goes on
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)

    Finaliser()
    print("went on", flush=True)

    def main(stop: threading.Event) -> int:
        print("stop asked" if stop.is_set() else "not asked", flush=True)
        return 0

    sys.exit(until_signal(main) if sys.argv[1] == "until" else __import__("ersac_hil.cli").cli.main(["--version"]))
"""


@pytest.mark.parametrize("where", ["until", "cli"])
def test_a_start_up_interrupt_that_a_finaliser_swallowed_still_stops_the_command(procs, where):
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(SWALLOWED), where], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # a background job's
    # children inherit SIGINT ignored, and Python keeps it so (the next test)
    procs.append(proc)
    out, err = proc.communicate(timeout=60)
    assert "Exception ignored" in err and "KeyboardInterrupt" in err  # Python itself swallowed it
    assert proc.returncode == 128 + signal.SIGINT
    assert out.split("\n")[:2] == (["went on", "stop asked"] if where == "until" else ["went on", ""])


def test_an_ignored_sigint_stays_ignored(procs):
    proc = _python("""
        import signal
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        from ersac_hil.lifecycle import note_early_interrupts
        note_early_interrupts()
        print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN, flush=True)
    """)
    procs.append(proc)
    assert _line(proc) == "True"


def test_kill_tree_reaches_grandchildren_and_their_groups(procs):
    proc = _python(f"""
        import subprocess, sys, time
        child = subprocess.Popen([sys.executable, "-c", {STUBBORN!r}], stdout=subprocess.PIPE, text=True,
                                 start_new_session=True)
        child.stdout.readline()
        print(child.pid, flush=True)
        time.sleep(600)
    """)
    procs.append(proc)
    grandchild = int(_line(proc))
    assert {proc.pid, grandchild} <= set(descendants(os.getpid()))
    assert kill_tree(signal.SIGKILL, proc.pid) == 1
    wait_until(lambda: gone(grandchild), what="the grandchild killed")
    assert proc.poll() is None  # the root itself is the caller's
    assert set(descendants(proc.pid)) <= {grandchild}


def test_a_child_dies_with_its_parent_even_ignoring_sigterm(procs, tmp_path):
    proc = _python(f"""
        import pathlib, time
        from ersac_hil.stack import Child, child_env
        child = Child("stubborn", [{sys.executable!r}, "-c", {STUBBORN!r}], pathlib.Path({str(tmp_path)!r}),
                      child_env())
        child.wait_for("ready", 60)
        print(child.pid, flush=True)
        time.sleep(600)
    """)
    procs.append(proc)
    child = int(_line(proc))
    os.kill(proc.pid, signal.SIGKILL)  # no chance to stop its child
    proc.wait()
    wait_until(lambda: gone(child), what="the child killed by the kernel with its parent")


def test_a_command_that_fails_after_a_start_up_interrupt_exits_130_not_1(monkeypatch, capsys):
    """A KeyboardInterrupt in an extension module's import comes out as its ImportError; after a
    recorded SIGINT that is the interrupt's exit, not a failure's."""
    import argparse

    from ersac_hil import cli, lifecycle

    def command(args):
        try:
            lifecycle._early_interrupt(signal.SIGINT, None)  # what the handler does on SIGINT
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None

    class Parser:
        prog = "ersac-hil"

        def parse_args(self, argv):
            return argparse.Namespace(verbose=0, command="x", func=command)

    monkeypatch.setattr(cli, "build_parser", Parser)
    assert cli.main(["x"]) == 128 + signal.SIGINT
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(Parser, "parse_args", lambda self, argv: argparse.Namespace(
        verbose=0, command="x", func=lambda args: int("not a number")))
    assert cli.main(["x"]) == 1  # without one, an error is still an error
    assert "ValueError" in capsys.readouterr().err
