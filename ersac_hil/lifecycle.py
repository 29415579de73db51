"""Process lifecycle in one place: run a service until SIGINT/SIGTERM, then stop it cleanly.

Every long-running ``ersac-hil`` subcommand (hub, agent, daemon, router, demo) is a
``Service`` (``start()`` / ``stop()``); ``serve`` installs the signal handlers, waits, and
always calls ``stop()``, so no child process, session or port outlives the command.
"""
from __future__ import annotations

import signal
import threading
from typing import Protocol


class Service(Protocol):
    def start(self) -> None: ...
    def stop(self) -> None: ...


def serve(service: Service, until: threading.Event | None = None) -> int:
    """Start ``service``, block until SIGINT/SIGTERM (or ``until`` is set), stop it.

    Returns 130 after SIGINT, 143 after SIGTERM, 0 when ``until`` ended it.
    """
    stop = until or threading.Event()
    received: list[int] = []

    def on_signal(signum, frame) -> None:
        received.append(signum)
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        service.start()
        while not stop.wait(0.2):
            pass
    finally:
        try:
            service.stop()
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
    if not received:
        return 0
    return 128 + received[0]
