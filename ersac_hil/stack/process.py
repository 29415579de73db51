"""Child processes of a stack: each in its own process group, its output in a log file, stopped
with SIGTERM and then SIGKILL, and killed by the kernel if the process that started it dies
(``PR_SET_PDEATHSIG``), so no child outlives its parent."""
from __future__ import annotations

import ctypes
import functools
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["GRACE_S", "Child", "ChildFailed", "child_env", "cli_argv", "die_with_parent"]

GRACE_S = 5.0

_PR_SET_PDEATHSIG = 1
_libc: ctypes.CDLL | None = None


def _prctl() -> Callable[..., int] | None:
    """libc's ``prctl``, loaded in the parent (loading a library between fork and exec of a
    threaded process can deadlock); ``None`` off Linux."""
    global _libc
    if _libc is None:
        try:
            _libc = ctypes.CDLL(None, use_errno=True)
        except OSError:
            return None
    return getattr(_libc, "prctl", None)


def die_with_parent(parent: int, prctl: Callable[..., int] | None = None) -> None:
    """Runs in the child between fork and exec: the kernel SIGKILLs the child when the thread
    that started it dies (``PR_SET_PDEATHSIG``), and it dies at once if ``parent`` (the
    starter's pid) is already gone (it died between fork and here).

    SIGKILL, not SIGTERM: once the parent is gone nobody waits for a graceful stop (that is
    the parent's job while it lives, :meth:`Child.stop`), and a child may not act on SIGTERM
    for a long while (a simulator holds it pending during its set-up; a process in a long
    native call runs no Python signal handler), which left children re-parented to init.
    The parent's thread must outlive the child: start children from the main thread or from
    a thread that stops them before it ends."""
    if prctl is not None:
        prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)


class ChildFailed(RuntimeError):
    """A child process exited early or did not become ready."""


class Child:
    """One child process in its own process group; output to a log file (and optionally echoed).

    The group stays in the demo's session (not ``setsid``): on Linux with autogroup scheduling
    every session is a scheduling group of its own, and a simulator and an agent in two groups
    handing every SYNC cycle to each other ran their episodes 15-20 % slower (docs/performance.md).

    Args:
        name: short name for messages and the log file.
        argv: the command.
        log_dir: where ``<name>.log`` goes.
        echo: called with every output line (e.g. print), or ``None``.
    """

    def __init__(self, name: str, argv: Sequence[str], log_dir: Path, env: dict[str, str],
                 echo: Callable[[str], None] | None = None) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_dir / f"{name}.log"
        self._echo = echo
        self._lines: list[str] = []
        self._cond = threading.Condition()
        self._terminated = False
        self._log = open(self.log_path, "w", buffering=1)
        self._log.write("$ " + " ".join(self.argv) + "\n")
        self.proc = subprocess.Popen(
            self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, process_group=0, preexec_fn=functools.partial(die_with_parent, os.getpid(), _prctl()), text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read, name=f"{name}-output", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self._log.write(line + "\n")
            if self._echo is not None:
                self._echo(line)
            with self._cond:
                self._lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def lines(self) -> list[str]:
        """The output lines so far."""
        with self._cond:
            return list(self._lines)

    def wait_for(self, pattern: str, timeout_s: float, stop: threading.Event | None = None) -> re.Match:
        """Wait for an output line matching ``pattern``; raise ChildFailed on exit/timeout."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._cond:
            while True:
                for line in self._lines[seen:]:
                    match = regex.search(line)
                    if match:
                        return match
                seen = len(self._lines)
                if stop is not None and stop.is_set():
                    raise ChildFailed(f"{self.name}: interrupted")
                if not self.alive() and not self._reader.is_alive():
                    raise ChildFailed(f"{self.name} exited with {self.proc.returncode} before "
                                      f"printing /{pattern}/; see {self.log_path}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ChildFailed(f"{self.name} did not print /{pattern}/ within {timeout_s:g} s; "
                                      f"see {self.log_path}")
                self._cond.wait(min(left, 0.2))

    def terminate(self) -> None:
        """SIGTERM the process group, once (a second SIGTERM would ask an ``ersac-hil`` child for
        its forced exit, ``lifecycle.until_signal``)."""
        if self.alive() and not self._terminated:
            self._terminated = True
            self._signal(signal.SIGTERM)

    def stop(self, grace_s: float = GRACE_S) -> int | None:
        """SIGTERM the process group (unless :meth:`terminate` did), SIGKILL it after ``grace_s``;
        returns the exit code. Idempotent."""
        if self._log.closed:
            return self.proc.returncode
        if self.alive():
            self.terminate()
            try:
                self.proc.wait(max(grace_s, 0.0))
            except subprocess.TimeoutExpired:
                self._log.write(f"[demo] {self.name} ignored SIGTERM for {grace_s:g} s: SIGKILL\n")
                self._signal(signal.SIGKILL)
                self.proc.wait(5.0)
        self._signal(signal.SIGKILL)  # stragglers left in the group
        self._reader.join(2.0)
        self._log.close()
        return self.proc.returncode

    def _signal(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


def cli_argv(*args: str) -> list[str]:
    """``python -m ersac_hil.cli ARGS`` with this interpreter."""
    return [sys.executable, "-m", "ersac_hil.cli", *args]


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    for key, value in (("OPENBLAS_NUM_THREADS", "1"), ("OMP_NUM_THREADS", "1"), ("MUJOCO_GL", "egl")):
        env.setdefault(key, value)
    env["PYTHONUNBUFFERED"] = "1"
    return env
