"""Per-robot identities (``certs init --robot ubot1 --robot ubot2``): each robot's agent and
simulator certificates speak only for that robot - its episode keys and its CAN channel -
through the router and through a simulator's direct CAN link.

Real Zenoh: a router as ``certs init`` configures it on a loopback address of its own, real
sessions and CAN-over-Zenoh buses with the generated configs; free ports.
"""
from __future__ import annotations

import time

import can
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.certs import CertError, init_certs, role_of_config
from ersac_hil.cli import main
from ersac_hil.roles import ROBOT_ROLES, ROLES, access_control, identities, parse_identity
from ersac_hil.zenoh_session import EmbeddedRouter, ZenohOptions, free_tcp_port, resolve_config, session_scope
from protocol.zenoh import KeySpace

HOST = "127.0.0.9"
ROBOTS = ("ubot1", "ubot2")
TIMEOUT = 10.0


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """A per-robot certificate set and its router; yields the set (``configs[name]``)."""
    certs = init_certs(tmp_path_factory.mktemp("fleet"), router=(f"tls/{HOST}:{free_tcp_port(HOST)}",),
                       robots=ROBOTS)
    with EmbeddedRouter(config=resolve_config(ZenohOptions(config_file=str(certs.configs["router"])),
                                              mode="router")):
        yield certs


def _options(fleet, name: str) -> ZenohOptions:  # noqa: ANN001
    return ZenohOptions(config_file=str(fleet.configs[name]))


def _bus(fleet, name: str, channel: str, **kwargs) -> can.BusABC:  # noqa: ANN001
    return can.Bus(interface="zenoh", channel=channel, zenoh_config=str(fleet.configs[name]), **kwargs)


def _heard(sender: can.BusABC, receiver: can.BusABC, arbitration_id: int) -> bool:
    """Send until ``receiver`` hears the frame (declarations propagate asynchronously)."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        sender.send(can.Message(arbitration_id=arbitration_id, data=b"\x01", is_extended_id=False))
        got = receiver.recv(0.05)
        if got is not None and got.arbitration_id == arbitration_id:
            return True
    return False


def _drain(bus: can.BusABC, wait_s: float = 0.5) -> list[int]:
    return [m.arbitration_id for m in iter(lambda: bus.recv(wait_s), None)]


def _assert_closed_to_the_stranger(sim: can.BusABC, agent: can.BusABC, stranger: can.BusABC) -> None:
    """The robot's simulator and agent talk both ways; frames of another robot's identity on
    the channel never reach the simulator, and it never hears the simulator."""
    assert _heard(agent, sim, 0x201) and _heard(sim, agent, 0x181)
    _drain(sim), _drain(agent)
    for _ in range(20):
        stranger.send(can.Message(arbitration_id=0x7, data=b"\x00", is_extended_id=False))
    agent.send(can.Message(arbitration_id=0x202, data=b"\x02", is_extended_id=False))
    heard = _drain(sim)
    assert 0x202 in heard and 0x7 not in heard  # the stranger cannot write on the bus
    sim.send(can.Message(arbitration_id=0x182, data=b"\x02", is_extended_id=False))
    assert agent.recv(TIMEOUT) is not None
    assert stranger.recv(0.5) is None  # nor hear it


def test_the_set_has_one_agent_and_one_simulator_per_robot_and_no_fleet_wide_ones(fleet):
    names = [name for name, _, _ in identities(ROBOTS)]
    assert set(fleet.configs) == set(names)
    assert {"agent", "simulator"}.isdisjoint(fleet.configs)
    for name in names:
        assert role_of_config(fleet.configs[name]) == (name if name != "router" else "router")
    acl = access_control(robots=ROBOTS)
    rules = {r["id"]: r for r in acl["rules"]}
    for robot in ROBOTS:
        for role in ROBOT_ROLES:
            (policy,) = [p for p in acl["policies"] if p["subjects"] == [f"{role}-{robot}"]]
            # what it may send or serve: its own keys and its ROS namespace only
            keys = {k for i in policy["rules"] for k in rules[i]["key_exprs"]
                    if rules[i]["messages"] != ["declare_subscriber"] or rules[i]["flows"] != ["egress"]}
            own_ros = {f"0/{robot}/**", f"@ros2_lv/0/*/*/*/*/*/%{robot}/**"}
            assert keys and all(k.startswith(f"ersac/{robot}/") or k == f"can/{robot}" or k in own_ros
                                for k in keys), keys
            # what it is told of: subscribers on its keys, and (an agent) the ROS domain's readers
            told = {k for i in policy["rules"] for k in rules[i]["key_exprs"]} - keys
            assert all(k.startswith(f"ersac/{robot}/") or k in (f"can/{robot}", "0/**") for k in told), told
            assert ("0/**" in told) == (role == "agent")


@given(st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,20}", fullmatch=True), st.sampled_from(ROBOT_ROLES))
def test_identities_name_their_role_and_robot(robot, role):
    assert parse_identity(f"{role}-{robot}") == (role, robot)
    assert all(parse_identity(name) == (r, rb) for name, r, rb in identities((robot,)))


@pytest.mark.parametrize("name", ["daemon-ubot1", "agentubot1", "agent-", "", "root"])
def test_other_names_are_no_identity(name):
    assert name not in ROLES
    with pytest.raises(ValueError, match="no ersac-hil identity"):
        parse_identity(name)


def test_bad_robot_names_are_refused_and_nothing_is_written(tmp_path, capsys):
    for robots in (("a/b",), ("ubot*",), ("u", "u")):
        with pytest.raises(CertError, match="robot"):
            init_certs(tmp_path / "x", robots=robots)
    assert main(["certs", "init", str(tmp_path / "y"), "--robot", "ubot 1"]) == 2
    assert "robot 'ubot 1'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_an_agent_serves_only_its_own_robots_episodes(fleet):
    asked: list[str] = []
    with (session_scope(resolve_config(_options(fleet, "agent-ubot1"))) as agent,
          session_scope(resolve_config(_options(fleet, "daemon"))) as daemon):
        own, other = KeySpace("ubot1"), KeySpace("ubot2")
        queryables = [agent.declare_queryable(k.episode_run, lambda q: (asked.append(str(q.key_expr)),
                                                                         q.reply(q.key_expr, b"ok")))
                      for k in (own, other)]
        tokens = [agent.liveliness().declare_token(k.agent_session(agent.info.zid())) for k in (own, other)]
        try:
            def replies(keys: KeySpace) -> list:
                return [r for r in daemon.get(keys.episode_run, payload=b"{}", timeout=2,
                                              target=zenoh.QueryTarget.ALL,
                                              consolidation=zenoh.ConsolidationMode.NONE) if r.ok]
            deadline = time.monotonic() + TIMEOUT
            while not replies(own) and time.monotonic() < deadline:
                pass
            assert len(replies(own)) == 1
            assert replies(other) == []  # its queryable for ubot2 is never routed to
            assert list(daemon.liveliness().get(other.agent_sessions, timeout=2)) == []
            assert list(daemon.liveliness().get(own.agent_sessions, timeout=2))
        finally:
            for t in tokens:
                t.undeclare()
            for q in queryables:
                q.undeclare()
    assert asked and set(asked) == {own.episode_run}


def test_a_robots_can_channel_is_closed_to_the_other_robots_identities(fleet):
    sim1, sim2 = _bus(fleet, "simulator-ubot1", "ubot1"), _bus(fleet, "simulator-ubot2", "ubot2")
    agent1_on_2, agent2 = _bus(fleet, "agent-ubot1", "ubot2"), _bus(fleet, "agent-ubot2", "ubot2")
    try:
        _assert_closed_to_the_stranger(sim2, agent2, agent1_on_2)
        agent1 = _bus(fleet, "agent-ubot1", "ubot1")
        try:
            assert _heard(agent1, sim1, 0x203)  # its own channel works
        finally:
            agent1.shutdown()
    finally:
        for bus in (agent2, agent1_on_2, sim2, sim1):
            bus.shutdown()


def test_a_per_robot_simulators_direct_link_admits_only_its_robots_agent(fleet):
    endpoint = f"tls/{HOST}:{free_tcp_port(HOST)}"  # a name on the simulator's certificate
    sim = _bus(fleet, "simulator-ubot1", "ubot1", listen=endpoint)
    agent, stranger = (_bus(fleet, "agent-ubot1", f"ubot1@{endpoint}"), _bus(fleet, "agent-ubot2", f"ubot1@{endpoint}"))
    try:
        _assert_closed_to_the_stranger(sim, agent, stranger)
    finally:
        for bus in (stranger, agent, sim):
            bus.shutdown()
