"""Waiting on conditions with a deadline: the one way tests synchronise with threads and
processes (never a bare sleep)."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

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
