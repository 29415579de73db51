"""``ersac-hil dashboard`` refuses what it cannot serve with one line and the documented exit code."""
from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.dashboard.cli import is_read_only
from ersac_hil.zenoh_session import EmbeddedRouter, free_tcp_port

ROOT = Path(__file__).resolve().parents[3]


def _dashboard(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ersac_hil.cli", "dashboard", *args], capture_output=True,
                          text=True, timeout=60, cwd=ROOT)


@pytest.mark.parametrize("args, message", [
    (("--host", "localhost"), "not an IP address"),
    (("--port", "70000"), "not in 0..65535"),
    (("--critic-points", "1"), "--critic-points"),
    (("--robot", "a/b"), "robot"),
    (("--zenoh-config", "/nonexistent/dashboard.json5"), "/nonexistent/dashboard.json5"),
    (("--zenoh", "tcp/10.1.2.3:7447"), "loopback"),
])
def test_invalid_arguments_exit_2(args, message):
    done = _dashboard(*args)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("ersac-hil: ") and message in done.stderr and "Traceback" not in done.stderr


def test_no_router_exits_1():
    done = _dashboard("--zenoh", f"tcp/127.0.0.1:{free_tcp_port()}", "--port", "0")
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr


def test_port_in_use_exits_1():
    with EmbeddedRouter() as router, socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        done = _dashboard("--zenoh", router.endpoint, "--port", str(taken.getsockname()[1]))
    assert done.returncode == 1 and "cannot listen on 127.0.0.1" in done.stderr, done.stderr


@pytest.mark.parametrize("role, flag, read_only", [
    (None, False, False), ("operator", False, False), ("operator", True, True), (None, True, True),
    ("observer", False, True), ("daemon", False, True), ("agent", False, True), ("router", False, True),
])
def test_only_an_operator_or_an_uncertified_session_gets_controls(role, flag, read_only):
    assert is_read_only(role, flag) is read_only
