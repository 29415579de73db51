"""Process lifecycle in one place: run until SIGINT/SIGTERM, then stop cleanly; a second signal
stops at once.

Every long-running ``ersac-hil`` subcommand is either a ``Service`` (``start()`` / ``stop()``:
hub, agent, daemon, router) run by ``serve``, or a blocking function that watches a stop
event (the demo, reproduce) run by ``until_signal``. Both install the signal handlers, always
clean up, restore the previous handlers, and return 128 + N after signal N, so no child
process, session or port outlives the command. The first SIGINT/SIGTERM asks for a graceful
stop; a second one, while that stop is under way, kills every process this one started
(``kill_tree``: its descendants and their process groups, SIGKILL) and exits with 128 + N of
the first at once. (``python -m firmware_sim`` cannot import this package and waits for its
signals with ``signal.sigwait`` instead.)

Before those handlers are in, Python's own SIGINT handler raises ``KeyboardInterrupt`` wherever
the interpreter is, and where that is a finaliser or a weakref callback (the import machinery's
module locks have one) the interpreter prints "Exception ignored" and goes on: a Ctrl-C during
start-up was lost and the command ran to its end (seen: the demo interrupted 0.27 s after it
started finished its five episodes with exit 0). :func:`note_early_interrupts`, the first thing
``ersac_hil.cli`` does, keeps that behaviour but records the signal, and :func:`until_signal`
(and ``cli.main``) stop at once for one recorded before them; ``cli.main`` also exits 128 + N,
not 1, when the command failed with an error after such a SIGINT (an extension module whose
import the ``KeyboardInterrupt`` hit says "ImportError: initialization failed"). A SIGINT while
CPython itself initialises (before any module of ours runs) is the interpreter's "Fatal Python
error: init_...", exit 1.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Protocol

__all__ = ["SIGNALS", "Service", "descendants", "kill_tree", "note_early_interrupts", "serve", "take_early",
           "until_signal"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_early: list[int] = []  # SIGINTs that came before until_signal's handlers (note_early_interrupts)


def note_early_interrupts() -> None:
    """Replace Python's default SIGINT handler by one that also records the signal (then raises
    ``KeyboardInterrupt`` as before); an ignored SIGINT (a background job) stays ignored. Main
    thread only; elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _early_interrupt)


def _early_interrupt(signum, frame) -> None:  # noqa: ANN001
    _early.append(signum)
    raise KeyboardInterrupt


def take_early() -> int | None:
    """The first SIGINT recorded by :func:`note_early_interrupts` and not taken yet, or ``None``
    (a ``KeyboardInterrupt`` that was swallowed on its way up)."""
    first = _early[0] if _early else None
    _early.clear()
    return first


class Service(Protocol):
    def start(self) -> None: ...
    def stop(self) -> None: ...


def descendants(pid: int) -> list[int]:
    """The pids of every living descendant of ``pid`` (children first), from ``/proc``; empty
    where there is no ``/proc``."""
    children: dict[int, list[int]] = {}
    try:
        entries = [e.name for e in os.scandir("/proc") if e.name.isdigit()]
    except OSError:
        return []
    for name in entries:
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                stat = f.read()
        except OSError:  # gone meanwhile
            continue
        ppid = int(stat[stat.rindex(b")") + 2:].split()[1])
        children.setdefault(ppid, []).append(int(name))
    found: list[int] = []
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(0), ()):
            found.append(child)
            todo.append(child)
    return found


def kill_tree(sig: int = signal.SIGKILL, pid: int | None = None) -> int:
    """Send ``sig`` to every descendant of ``pid`` (default: this process) and to their process
    groups (which also reach a group's members that were re-parented), never to this process's
    own group. Returns how many descendants there were."""
    pid = os.getpid() if pid is None else pid
    own = os.getpgid(0)
    found = descendants(pid)
    for child in found:
        try:
            group = os.getpgid(child)
            if group != own:
                os.killpg(group, sig)
            os.kill(child, sig)
        except (ProcessLookupError, PermissionError):
            pass
    return len(found)


def until_signal(main: Callable[[threading.Event], int], stop: threading.Event | None = None) -> int:
    """Run ``main(stop)``; SIGINT/SIGTERM set ``stop`` (``main`` must return soon after); a
    second signal kills this process's tree and exits at once (``os._exit``).

    Returns 128 + the first signal's number if one came, else what ``main`` returned.
    """
    stop = stop or threading.Event()
    received: list[int] = []

    def on_signal(signum, frame) -> None:  # noqa: ANN001
        received.append(signum)
        if len(received) > 1:
            _force_exit(128 + received[0])
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in SIGNALS}
    early = take_early()
    if early is not None:  # it came before these handlers and was swallowed: stop now
        received.append(early)
        stop.set()
    try:
        code = main(stop)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 128 + received[0] if received else code


def _force_exit(code: int) -> None:
    killed = kill_tree(signal.SIGKILL)
    try:
        os.write(sys.stderr.fileno(), f"second signal: {killed} child process(es) killed, exiting now\n".encode())
    except (OSError, ValueError):
        pass
    os._exit(code)


def serve(service: Service, until: threading.Event | None = None) -> int:
    """Start ``service``, block until SIGINT/SIGTERM (or ``until`` is set), stop it.

    Returns 130 after SIGINT, 143 after SIGTERM, 0 when ``until`` ended it.
    """
    def run(stop: threading.Event) -> int:
        try:
            service.start()
            while not stop.wait(0.2):
                pass
        finally:
            service.stop()
        return 0

    return until_signal(run, until)
