"""Pin BLAS to one thread around the numerical kernels.

The machine has 2 cores; OpenBLAS on its default threading oversubscribes and makes the
small (n <= a few hundred) matrix products of the critic ~25x slower (measured: a VHGP fit
at n ~ 100 took 0.1-0.4 s pinned, ~25x that on OpenBLAS's default threading).
`single_threaded_blas()` limits every BLAS library loaded in the process (numpy's and
scipy's OpenBLAS) for the duration of a call and restores the previous limits after.

The limit is process-wide (OpenBLAS has one thread pool a process), and several threads
may compute at once (two daemons in one process, a fleet's workers): the limit is set by
the first thread that enters and restored by the last one that leaves, under one lock, so
it stays at 1 while any thread is inside.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import scipy.linalg  # noqa: F401  (load scipy's BLAS before the controller enumerates libraries)
from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_lock = threading.Lock()
_inside = 0
"""Entries into ``single_threaded_blas`` not yet left, of every thread (nested ones included)."""
_limiter = None
"""threadpoolctl's limiter that set the limit (it holds the limits to restore), while ``_inside``."""


def _get_controller() -> ThreadpoolController:
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller


def _no_controlling_thread(controller: ThreadpoolController) -> None:
    """Forget which thread controls OpenBLAS's limits (threadpoolctl >= 3.6 lets one thread
    at a time set them and silently ignores the others): the limit is set by one thread and
    restored by another, both under ``_lock``."""
    for cls in {type(lib) for lib in controller.lib_controllers}:
        clear = getattr(cls, "clear_controlling_thread", None)
        if clear is not None:
            clear(force=True)


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: BLAS runs on one thread inside (re-entrant, thread-safe, ~10 us overhead)."""
    global _inside, _limiter
    with _lock:
        if _inside == 0:
            controller = _get_controller()
            _no_controlling_thread(controller)
            _limiter = controller.limit(limits=1, user_api="blas")
            _no_controlling_thread(controller)
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0:
                limiter, _limiter = _limiter, None
                _no_controlling_thread(_get_controller())
                limiter.restore_original_limits()
                _no_controlling_thread(_get_controller())


def blas_description() -> str:
    """One line naming the BLAS libraries and their thread counts (for benchmark output)."""
    infos = _get_controller().info()
    parts = [f"{i['internal_api']} {i.get('version', '?')} threads={i['num_threads']}" for i in infos]
    return "; ".join(parts) if parts else "no BLAS library detected"
