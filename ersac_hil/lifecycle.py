"""Process lifecycle in one place: run until SIGINT/SIGTERM, then stop cleanly.

Every long-running ``ersac-hil`` subcommand is either a ``Service`` (``start()`` / ``stop()``:
hub, agent, daemon, router) run by ``serve``, or a blocking function that watches a stop
event (the demo) run by ``until_signal``. Both install the signal handlers, always clean up,
restore the previous handlers, and return 128 + N after signal N, so no child process,
session or port outlives the command. (``python -m firmware_sim`` cannot import this package
and waits for its signals with ``signal.sigwait`` instead.)
"""
from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from typing import Protocol

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Service(Protocol):
    def start(self) -> None: ...
    def stop(self) -> None: ...


def until_signal(main: Callable[[threading.Event], int], stop: threading.Event | None = None) -> int:
    """Run ``main(stop)``; SIGINT/SIGTERM set ``stop`` (``main`` must return soon after).

    Returns 128 + the first signal's number if one came, else what ``main`` returned.
    """
    stop = stop or threading.Event()
    received: list[int] = []

    def on_signal(signum, frame) -> None:  # noqa: ANN001
        received.append(signum)
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in SIGNALS}
    try:
        code = main(stop)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 128 + received[0] if received else code


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
