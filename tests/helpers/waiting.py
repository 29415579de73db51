"""Waiting on conditions with a deadline: the one way tests synchronise with threads and
processes (never a bare sleep)."""
from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest

T = TypeVar("T")

DEFAULT_TIMEOUT_S = 60.0
"""Generous on purpose: a deadline only bounds how long a broken test hangs; it is no
statement about speed (speed is measured in bench/)."""


def wait_until(predicate: Callable[[], T], timeout_s: float = DEFAULT_TIMEOUT_S, poll_s: float = 0.01,
               what: str = "condition") -> T:
    """Call ``predicate`` until it returns something truthy and return that; fail the test
    (naming ``what``) if ``timeout_s`` passes first."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"{what} not met within {timeout_s} s")
        time.sleep(poll_s)


def wait_for_match(entity: Any, timeout_s: float = 5.0, poll_s: float = 0.002) -> bool:
    """Wait until a :class:`zenoh.Publisher` or :class:`zenoh.Querier` has a matching
    subscriber/queryable (declarations propagate asynchronously through the router).

    Returns:
        whether a match appeared within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        if entity.matching_status.matching:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


def wait_for_store(db: Path, predicate: Callable[..., object], timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """Wait until ``predicate(store, run_id)`` holds for the first run of the SQLite store at
    ``db``, which another process is writing (it may not exist yet, or be half made)."""
    from ersac_hil.daemon.store import Store

    def reached() -> bool:
        if not db.exists():
            return False
        try:
            with Store(db, readonly=True) as store:
                runs = store.runs()
                return bool(runs and predicate(store, runs[0].run_id))
        except Exception:  # noqa: BLE001 - the writer may still be creating the schema
            return False
    wait_until(reached, timeout_s, what="the daemon's store state")
