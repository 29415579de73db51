"""Waiting on conditions with a deadline: the one way tests synchronise with threads and
processes (never a bare sleep)."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest

from ersac_hil.stack.waiting import NotInTime
from ersac_hil.stack.waiting import wait_until as stack_wait_until

T = TypeVar("T")

DEFAULT_TIMEOUT_S = 60.0
"""Generous on purpose: a deadline only bounds how long a broken test hangs; it is no
statement about speed (speed is measured in bench/)."""


def wait_until(predicate: Callable[[], T], timeout_s: float = DEFAULT_TIMEOUT_S, poll_s: float = 0.01,
               what: str = "condition") -> T:
    """Call ``predicate`` until it returns something truthy and return that; fail the test
    (naming ``what``) if ``timeout_s`` passes first (``ersac_hil.stack.waiting.wait_until``, the
    one implementation, with the test's failure instead of its ``NotInTime``)."""
    try:
        return stack_wait_until(predicate, timeout_s, what, poll_s)
    except NotInTime as exc:
        pytest.fail(str(exc))


def wait_for_match(entity: Any, timeout_s: float = 5.0, poll_s: float = 0.002) -> bool:
    """Wait until a :class:`zenoh.Publisher` or :class:`zenoh.Querier` has a matching
    subscriber/queryable (declarations propagate asynchronously through the router).

    Returns:
        whether a match appeared within ``timeout_s``.
    """
    try:
        return stack_wait_until(lambda: entity.matching_status.matching, timeout_s, "a match", poll_s)
    except NotInTime:
        return False


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
