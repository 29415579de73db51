"""Pin BLAS to one thread around the numerical kernels.

The machine has 2 cores; OpenBLAS on its default threading oversubscribes and makes the
small (n <= a few hundred) matrix products of the critic ~25x slower (measured: a VHGP fit
at n ~ 100 took 0.1-0.4 s pinned, ~25x that on OpenBLAS's default threading).
`single_threaded_blas()` limits every BLAS library loaded in the process (numpy's and
scipy's OpenBLAS) for the duration of a call and restores the previous limits after.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import scipy.linalg  # noqa: F401  (load scipy's BLAS before the controller enumerates libraries)
from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_depth = 0


def _get_controller() -> ThreadpoolController:
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: BLAS runs on one thread inside (re-entrant, ~10 us overhead)."""
    global _depth
    if _depth > 0:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    _depth = 1
    try:
        with _get_controller().limit(limits=1, user_api="blas"):
            yield
    finally:
        _depth = 0


def blas_description() -> str:
    """One line naming the BLAS libraries and their thread counts (for benchmark output)."""
    infos = _get_controller().info()
    parts = [f"{i['internal_api']} {i.get('version', '?')} threads={i['num_threads']}" for i in infos]
    return "; ".join(parts) if parts else "no BLAS library detected"
