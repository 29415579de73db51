"""single_threaded_blas() with several threads: BLAS's thread limit is process-wide (OpenBLAS
has one pool a process), so it stays at 1 while any thread is inside and comes back only once
the last one has left (two daemons in one process, each fitting its critic on a thread of its
own). Each thread's entries and exits are driven one at a time from the test (a command queue
per thread, every step acknowledged), so the interleaving is exactly the one drawn."""
from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from threadpoolctl import ThreadpoolController, threadpool_info

from ersac_hil.critic._blas import single_threaded_blas

OUTSIDE = 2
"""The limit the test sets outside (the suite runs with OPENBLAS_NUM_THREADS=1)."""
STEP_S = 30.0
"""How long a step may take before the test calls its thread hung (not a timing assertion)."""


def blas_limits() -> list[int]:
    """The thread limit of every BLAS library loaded, read from the libraries themselves."""
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


def _on_a_thread_of_its_own(job) -> None:  # noqa: ANN001
    """Run ``job`` on a thread that ends after it: threadpoolctl (>= 3.6) lets only the thread
    that last set OpenBLAS's limit set it again while that thread lives."""
    thread = threading.Thread(target=job)
    thread.start()
    thread.join()


@pytest.fixture(scope="module")
def outside() -> Iterator[None]:
    """The process's BLAS limit at ``OUTSIDE`` for the module's tests, as it was after."""
    if not blas_limits():
        pytest.skip("no BLAS library loaded")
    limiter = []
    _on_a_thread_of_its_own(lambda: limiter.append(ThreadpoolController().limit(limits=OUTSIDE, user_api="blas")))
    try:
        if set(blas_limits()) != {OUTSIDE}:
            pytest.skip(f"the BLAS libraries do not take a limit of {OUTSIDE} threads: {blas_limits()}")
        yield
    finally:
        _on_a_thread_of_its_own(limiter[0].restore_original_limits)


class Worker:
    """A thread that enters or leaves ``single_threaded_blas()`` when told, one step at a time."""

    def __init__(self) -> None:
        self._todo: queue.Queue[str] = queue.Queue()
        self._done: queue.Queue[BaseException | None] = queue.Queue()
        self._held: list[contextlib.AbstractContextManager] = []
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (step := self._todo.get()) != "quit":
            try:
                if step == "enter":
                    held = single_threaded_blas()
                    held.__enter__()
                    self._held.append(held)
                else:
                    self._held.pop().__exit__(None, None, None)
                self._done.put(None)
            except BaseException as exc:  # handed to the test
                self._done.put(exc)

    def step(self, what: str) -> None:
        self._todo.put(what)
        error = self._done.get(timeout=STEP_S)
        if error is not None:
            raise error

    @property
    def inside(self) -> int:
        return len(self._held)

    def close(self) -> None:
        while self._held:
            self.step("exit")
        self._todo.put("quit")
        self._thread.join(STEP_S)


@contextlib.contextmanager
def workers(n: int) -> Iterator[list[Worker]]:
    started = [Worker() for _ in range(n)]
    try:
        yield started
    finally:
        for w in started:
            w.close()


def test_the_first_thread_out_leaves_the_limit_on_for_the_one_still_inside(outside):
    """Two daemons' critic fits overlap: the first to finish must not give the second BLAS's
    threads back (it did: the nesting depth was one global, so the thread that set the limit
    restored it on its way out whoever was still inside)."""
    with workers(2) as (a, b):
        a.step("enter")
        b.step("enter")
        a.step("exit")
        assert set(blas_limits()) == {1}, "b computes with the limit lifted"
        b.step("exit")
        assert set(blas_limits()) == {OUTSIDE}


def test_the_limit_comes_back_after_the_last_thread_whichever_set_it(outside):
    with workers(2) as (a, b):
        a.step("enter")
        b.step("enter")
        b.step("exit")
        assert set(blas_limits()) == {1}
        a.step("exit")
        assert set(blas_limits()) == {OUTSIDE}
        b.step("enter")  # again, from the other thread first: it sets the limit now
        assert set(blas_limits()) == {1}
        b.step("exit")
        assert set(blas_limits()) == {OUTSIDE}


@st.composite
def interleavings(draw) -> list[tuple[int, str]]:  # noqa: ANN001
    """Up to three threads, each entering 1-2 times (nested) and leaving as often, in any order
    that keeps each thread's own: enters first, then its exits."""
    depths = draw(st.lists(st.integers(1, 2), min_size=1, max_size=3))
    tokens = draw(st.permutations([k for k, depth in enumerate(depths) for _ in range(2 * depth)]))
    seen = [0] * len(depths)
    steps = []
    for k in tokens:
        steps.append((k, "enter" if seen[k] < depths[k] else "exit"))
        seen[k] += 1
    return steps


@settings(max_examples=60, deadline=None)
@given(steps=interleavings())
def test_the_limit_is_one_exactly_while_any_thread_is_inside(outside, steps):
    n = 1 + max(k for k, _ in steps)
    with workers(n) as threads:
        for k, what in steps:
            threads[k].step(what)
            inside = sum(w.inside for w in threads)
            assert set(blas_limits()) == ({1} if inside else {OUTSIDE}), (k, what, inside)
