"""Shared fixtures: CAN backends available on this machine; the hypothesis profile (no deadlines).

``can_backend`` is parametrised over every backend; each test gets a fresh channel (a new
virtual channel name, a new loopback hub, a new CAN-over-Zenoh channel on the session's
embedded router) so tests never hear each other.
"""
from __future__ import annotations

import os
import uuid

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

# No per-example deadline: it is a timed assert (a busy machine makes any example slow);
# speed is measured in bench/.
settings.register_profile("ersac-hil", deadline=None)
settings.load_profile("ersac-hil")

from ersac_hil.canbus import LoopbackHub, vcan_status  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402

BACKENDS = ("virtual", "remote", "zenoh", "socketcan")


@pytest.fixture(scope="session")
def can_router():
    """The embedded Zenoh router CAN-over-Zenoh channels of the test session go through."""
    with EmbeddedRouter() as router:
        yield router


@pytest.fixture(params=BACKENDS)
def can_backend(request):
    """A ``BusConfig`` every participant of the test opens its own bus with."""
    kind = request.param
    if kind == "virtual":
        yield BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    elif kind == "remote":
        with LoopbackHub() as hub:
            yield hub.bus_config
    elif kind == "zenoh":
        router = request.getfixturevalue("can_router")
        yield BusConfig("zenoh", f"test-{uuid.uuid4().hex[:8]}@{router.endpoint}")
    else:
        status = vcan_status("vcan0")
        if not status.available:
            pytest.skip(f"socketcan/vcan0 unavailable: {status.reason}")
        yield BusConfig("socketcan", "vcan0")
