"""Child processes of the end-to-end tests: read their output up to a line, stop them, check that
nothing they started is left."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def group_killed_on_exit(proc: subprocess.Popen) -> Iterator[subprocess.Popen]:
    """Whatever the test does, ``proc``'s process group (started with ``start_new_session``)
    is SIGKILLed at the end if it still runs."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def lines_until(proc: subprocess.Popen, pattern: str, timeout_s: float) -> list[str]:
    """``proc``'s output lines up to and including the first that matches ``pattern``."""
    regex, lines = re.compile(pattern), []
    deadline = time.monotonic() + timeout_s
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line)
        if regex.search(line):
            return lines
        if time.monotonic() > deadline:
            break
    pytest.fail(f"no line /{pattern}/ within {timeout_s} s:\n" + "".join(lines))


def children(output: str) -> dict[str, int]:
    """The ``children name=pid ...`` line a stack prints, as {name: pid}."""
    match = re.search(r"children ((?:\S+=\d+ ?)+)$", output, re.M)
    assert match, output
    return {name: int(pid) for name, pid in (item.split("=") for item in match.group(1).split())}


def gone(pid: int) -> bool:
    """``pid`` runs no more (a zombie left for its parent to reap counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except OSError:
        return True


def running_with(marker: Path) -> list[int]:
    """Processes still running with ``marker`` (e.g. an output directory) on their command line."""
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                if str(marker).encode() in (proc / "cmdline").read_bytes():
                    pids.append(int(proc.name))
            except OSError:
                pass
    return pids
