"""A direct CAN-over-Zenoh link: a bus listening (``ZenohBus(listen=...)``), others connected to it.

Real Zenoh sessions on loopback, free ports. The conformance suite runs on such a link too
(``can_backend`` "zenoh-direct"); here: frames both ways and between the clients, the
listener's TLS and access control (the router's rules: only the agent and simulator roles
on the CAN keys), and the configurations refused.
"""
from __future__ import annotations

import json
import time
import uuid

import can
import pytest

from ersac_hil.canbus.direct import listener_config
from ersac_hil.roles import access_control
from ersac_hil.zenoh_session import ZenohConfigError, ZenohOptions, free_tcp_port

TIMEOUT = 10.0


def _link(sender: can.BusABC, receiver: can.BusABC, arbitration_id: int) -> can.Message | None:
    """Send until ``receiver`` hears one (declarations propagate asynchronously)."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        sender.send(can.Message(arbitration_id=arbitration_id, data=b"\x01", is_extended_id=False))
        got = receiver.recv(0.05)
        if got is not None:
            while receiver.recv(0.05) is not None:
                pass
            return got
    return None


def _buses(*specs: dict) -> list[can.BusABC]:
    opened: list[can.BusABC] = []
    try:
        for kwargs in specs:
            opened.append(can.Bus(interface="zenoh", **kwargs))
    except Exception:
        for bus in opened:
            bus.shutdown()
        raise
    return opened


def test_clients_hear_the_listener_and_each_other():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    name = f"d-{uuid.uuid4().hex[:8]}"
    listener, agent, recorder = _buses({"channel": name, "listen": endpoint},
                                       {"channel": f"{name}@{endpoint}"}, {"channel": f"{name}@{endpoint}"})
    try:
        assert f"listening on {endpoint}" in listener.channel_info
        assert _link(agent, listener, 0x201) is not None
        assert _link(listener, agent, 0x181) is not None
        assert _link(agent, recorder, 0x202) is not None  # the listener routes between its clients
        burst = [(0x181 + i, bytes([i])) for i in range(13)]
        listener.send_data_frames(burst)
        got = [agent.recv(TIMEOUT) for _ in burst]
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == burst  # in order
    finally:
        for bus in (recorder, agent, listener):
            bus.shutdown()


def test_tls_listener_serves_the_agent_and_keeps_other_roles_off(secure_can_router):
    configs = secure_can_router.configs
    host = "127.0.0.7"  # one of the names on the simulator's certificate
    endpoint = f"tls/{host}:{free_tcp_port(host)}"
    name = f"s-{uuid.uuid4().hex[:8]}"
    simulator, agent, observer = _buses(
        {"channel": name, "listen": endpoint, "zenoh_config": str(configs["simulator"])},
        {"channel": f"{name}@{endpoint}", "zenoh_config": str(configs["agent"])},
        {"channel": f"{name}@{endpoint}", "zenoh_config": str(configs["observer"])})
    try:
        assert _link(agent, simulator, 0x201) is not None and _link(simulator, agent, 0x181) is not None
        for _ in range(20):
            observer.send(can.Message(arbitration_id=0x7, data=b"\x00"))  # dropped by the listener's ACL
        agent.send(can.Message(arbitration_id=0x202, data=b"\x02"))
        heard = [m.arbitration_id for m in iter(lambda: simulator.recv(1.0), None)]
        assert 0x202 in heard and 0x7 not in heard
        simulator.send(can.Message(arbitration_id=0x182, data=b"\x02"))
        assert agent.recv(TIMEOUT) is not None
        assert observer.recv(0.2) is None  # nor does it hear the bus
    finally:
        for bus in (observer, agent, simulator):
            bus.shutdown()
    # without a certificate of the CA there is no link at all
    with pytest.raises(can.CanInitializationError):
        can.Bus(interface="zenoh", channel=f"{name}@tcp/{endpoint.split('/', 1)[1]}", connect_timeout=0.5)


def test_tls_listener_config_is_the_routers_access_control_with_client_certificates(secure_can_router):
    simulator = str(secure_can_router.configs["simulator"])
    config = listener_config(ZenohOptions(config_file=simulator), ["tls/127.0.0.1:7999"])

    def get(key: str):  # noqa: ANN202
        return json.loads(config.get_json(key))
    assert get("mode") == "peer" and get("listen/endpoints") == ["tls/127.0.0.1:7999"]
    assert get("connect/endpoints") == []  # not to the router of the file
    tls = get("transport/link/tls")
    assert tls["enable_mtls"] is True
    assert (tls["listen_certificate"], tls["listen_private_key"]) == (tls["connect_certificate"],
                                                                      tls["connect_private_key"])
    acl = get("access_control")
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert acl["policies"] == access_control()["policies"]


@pytest.mark.parametrize("listen, role, match", [
    (["tcp/192.0.2.1:7447"], None, "neither on loopback nor secured"),
    (["tcp/127.0.0.1:7447"], "simulator", "listen on tls/HOST:PORT"),
    (["tls/127.0.0.1:7447"], None, "needs a certificate"),
    ([], None, "at least one endpoint"),
])
def test_refused_listeners(secure_can_router, listen, role, match):
    options = ZenohOptions(config_file=str(secure_can_router.configs[role]) if role else None)
    with pytest.raises(ZenohConfigError, match=match):
        listener_config(options, listen)


def test_a_bad_listen_endpoint_is_a_python_can_init_error():
    with pytest.raises(can.CanInitializationError, match="PROTOCOL/HOST:PORT"):
        can.Bus(interface="zenoh", channel="c", listen="tcp/127.0.0.1")


@pytest.mark.parametrize("listener_low, client_low", [(True, "false"), ("0", True)])
def test_a_low_latency_end_and_a_default_end_still_link(listener_low, client_low):
    """Zenoh negotiates the transport per link: one end without the low-latency transport (a
    router's default session, a third-party bus) gets the universal one, frames as before."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    name = f"d-{uuid.uuid4().hex[:8]}"
    listener, client = _buses({"channel": name, "listen": endpoint, "lowlatency": listener_low},
                              {"channel": f"{name}@{endpoint}", "lowlatency": client_low})
    try:
        assert _link(client, listener, 0x201) is not None
        assert _link(listener, client, 0x181) is not None
        burst = [(0x181 + i, bytes([i])) for i in range(13)]
        listener.send_data_frames(burst)
        got = [client.recv(TIMEOUT) for _ in burst]
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == burst
    finally:
        for bus in (client, listener):
            bus.shutdown()
