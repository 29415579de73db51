"""Shared fixtures: CAN backends available on this machine; the hypothesis profile (no deadlines).

``can_backend`` is parametrised over every backend; each test gets a fresh channel (a new
virtual channel name, a new loopback hub, a new CAN-over-Zenoh channel on the session's
embedded router) so tests never hear each other. ``zenoh-tls`` is CAN over Zenoh through a
router as ``ersac-hil certs init`` configures it (TLS, client certificates, access control by
role), every participant with the ``agent`` role's config (the ``simulator`` role has the
same CAN rule). ``zenoh-direct`` is a direct link (``ersac_hil.canbus.direct``): every
participant, with the ``agent`` role's config, connects to a bus listening with the
``simulator`` role's config (TLS, client certificates, the router's access control) instead
of a router, and busy-polls (``busy_poll``) as ``ersac-hil demo``'s buses do. ``ipc`` is CAN
over a Unix socket (``ersac_hil.canbus.ipc``): every participant connects to a bus the fixture
keeps listening on a fresh socket path.
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

BACKENDS = ("virtual", "remote", "zenoh", "zenoh-tls", "zenoh-direct", "ipc", "socketcan")


@pytest.fixture(scope="session")
def can_router():
    """The embedded Zenoh router CAN-over-Zenoh channels of the test session go through."""
    with EmbeddedRouter() as router:
        yield router


@pytest.fixture(scope="session")
def secure_can_router(tmp_path_factory):
    """A router as ``certs init`` configures it (TLS, client certificates, access control by
    role) on a loopback address of its own; yields the certificate set (``configs[role]``)."""
    from ersac_hil.certs import init_certs
    from ersac_hil.zenoh_session import ZenohOptions, free_tcp_port, resolve_config
    host = "127.0.0.7"
    certs = init_certs(tmp_path_factory.mktemp("certs"), router=(f"tls/{host}:{free_tcp_port(host)}",))
    config = resolve_config(ZenohOptions(config_file=str(certs.configs["router"])), mode="router")
    with EmbeddedRouter(config=config):
        yield certs


@pytest.fixture(scope="session")
def can_listener(secure_can_router):
    """A bus listening as the simulator does on a direct link (``tls/`` on the secure router's
    address, the ``simulator`` role's config); yields its endpoint."""
    import can
    from ersac_hil.zenoh_session import free_tcp_port
    host = "127.0.0.7"
    endpoint = f"tls/{host}:{free_tcp_port(host)}"
    bus = can.Bus(interface="zenoh", channel="listener", listen=endpoint,
                  zenoh_config=str(secure_can_router.configs["simulator"]))
    try:
        yield endpoint
    finally:
        bus.shutdown()


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
    elif kind == "zenoh-direct":
        endpoint = request.getfixturevalue("can_listener")
        certs = request.getfixturevalue("secure_can_router")
        yield BusConfig("zenoh", f"test-{uuid.uuid4().hex[:8]}@{endpoint}",
                        options=(("zenoh_config", str(certs.configs["agent"])), ("busy_poll", "0.002")))
    elif kind == "ipc":
        import shutil
        import tempfile

        import can
        folder = tempfile.mkdtemp(prefix="can-")  # short: a socket path has at most 107 bytes
        path = os.path.join(folder, "bus.sock")
        listener = can.Bus(interface="ipc", channel=path, listen=True)
        listener.push_notifier([])  # it only relays: nothing queued for a recv() nobody calls
        try:
            yield BusConfig("ipc", path)
        finally:
            listener.shutdown()
            shutil.rmtree(folder, ignore_errors=True)
    elif kind == "zenoh-tls":
        certs = request.getfixturevalue("secure_can_router")
        yield BusConfig("zenoh", f"test-{uuid.uuid4().hex[:8]}",
                        options=(("zenoh_config", str(certs.configs["agent"])),))
    else:
        status = vcan_status("vcan0")
        if not status.available:
            pytest.skip(f"socketcan/vcan0 unavailable: {status.reason}")
        yield BusConfig("socketcan", "vcan0")
