"""Waiting on a condition with a deadline, the one way the stack's harnesses (and the tests,
through ``tests/helpers/waiting.py``) synchronise with other processes: poll, never a bare
sleep."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

__all__ = ["NotInTime", "wait_until"]

T = TypeVar("T")


class NotInTime(TimeoutError):
    """A condition :func:`wait_until` waited for did not hold within its deadline."""


def wait_until(predicate: Callable[[], T], timeout_s: float, what: str = "condition", poll_s: float = 0.01) -> T:
    """Call ``predicate`` every ``poll_s`` until it returns something truthy and return that.

    Raises:
        NotInTime: naming ``what``, once ``timeout_s`` passed first.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise NotInTime(f"{what} not met within {timeout_s:g} s")
        time.sleep(poll_s)
