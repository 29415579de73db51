"""Fixtures of the simulator's tests."""
from __future__ import annotations

import pytest

from firmware_sim.simulator import Simulator


@pytest.fixture(scope="module")
def sim() -> Simulator:
    """One simulator per test module (tests reset the scenario they need)."""
    return Simulator()
