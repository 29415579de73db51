"""The roles' access control for ROS 2 (``ersac_hil.roles.ros2_rules``) on a real router as
``certs init`` configures it: the agent's node publishes and declares its tokens, observers and
operators read them, the daemon sees nothing and an observer cannot publish."""
from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.certs import init_certs
from ersac_hil.roles import ROLES, access_control
from ersac_hil.ros2 import messages, names
from ersac_hil.ros2.bridge import Ros2Node
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.zenoh_session import EmbeddedRouter, ZenohOptions, free_tcp_port, resolve_config, session_scope
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.waiting import wait_until
from protocol.can.busconfig import BusConfig
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

HOST = "127.0.0.11"
TIMEOUT = 10.0
SAMPLE = b"\x00\x01\x00\x00"


@contextmanager
def _router(tmp_path_factory, name: str, **certs_args) -> Iterator:  # noqa: ANN001
    """``certs init`` (``certs_args``) and a real router with its config."""
    certs = init_certs(tmp_path_factory.mktemp(name), router=(f"tls/{HOST}:{free_tcp_port(HOST)}",), **certs_args)
    with EmbeddedRouter(config=resolve_config(ZenohOptions(config_file=str(certs.configs["router"])),
                                              mode="router")):
        yield certs


def _put_until(enough: Callable[[], bool], *nodes: Ros2Node, every_s: float = 0.02) -> None:
    """Each node puts an episode sample every ``every_s`` until ``enough()`` (at most TIMEOUT)."""
    deadline = time.monotonic() + TIMEOUT
    while not enough() and time.monotonic() < deadline:
        for node in nodes:
            node.put("episode", SAMPLE)
        time.sleep(every_s)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    with _router(tmp_path_factory, "ros2-acl") as certs:
        yield certs


def _session(deployment, role: str):  # noqa: ANN001
    return session_scope(resolve_config(ZenohOptions(config_file=str(deployment.configs[role]))))


def test_the_rules_give_ros2_to_the_agent_and_reading_to_operators_and_observers():
    acl = access_control(ros_domain=4)
    by_subject = {p["subjects"][0]: {r for r in p["rules"] if "-ros2-" in r} for p in acl["policies"]}
    assert {role for role in ROLES if by_subject.get(role)} == {"agent", "operator", "observer"}
    rules = {r["id"]: r for r in acl["rules"]}
    agent = [rules[i] for i in by_subject["agent"]]
    assert {(r["flows"][0], m, k) for r in agent for m in r["messages"] for k in r["key_exprs"]} == {
        ("ingress", "put", "4/**"), ("ingress", "liveliness_token", "@ros2_lv/4/**"),
        ("egress", "declare_subscriber", "4/**")}


def test_observers_see_the_agents_node_and_samples_and_others_do_not(deployment):
    got: dict[str, list] = {"observer": [], "daemon": [], "operator": []}
    with (_session(deployment, "agent") as agent, _session(deployment, "observer") as observer,
          _session(deployment, "daemon") as daemon, _session(deployment, "operator") as operator):
        subs = [s.declare_subscriber("0/**", lambda sample, role=role: got[role].append(str(sample.key_expr)))
                for role, s in (("observer", observer), ("daemon", daemon), ("operator", operator))]
        node = Ros2Node.declare(agent, Ros2Options(), "ubot1")
        try:
            _put_until(lambda: bool(got["observer"] and got["operator"]), node, every_s=0.05)
            assert got["observer"] and got["operator"]
            key = got["observer"][0]
            assert key.startswith("0/ubot1/episode/diagnostic_msgs::msg::dds_::DiagnosticStatus_/RIHS01_")
            tokens = [names.parse_token(str(r.ok.key_expr)) for r in observer.liveliness().get("@ros2_lv/0/**", timeout=2)]
            assert {t.kind for t in tokens} == {"NN", "MP"}
            assert {t.topic for t in tokens if t.kind == "MP"} == {f"/ubot1/{t}" for t in messages.TOPICS}
            assert list(daemon.liveliness().get("@ros2_lv/0/**", timeout=2)) == []
            # an observer's put is dropped at the router: the operator never hears it
            heard = len(got["operator"])
            for _ in range(20):
                observer.put("0/ubot1/joint_states/fake", b"x")
            node.put("episode", SAMPLE)  # a later sample of the agent's does arrive
            deadline = time.monotonic() + TIMEOUT
            while len(got["operator"]) == heard and time.monotonic() < deadline:
                time.sleep(0.05)
            assert "0/ubot1/joint_states/fake" not in got["operator"]
            # every sample arrives, not only the first: the agent learns of the readers'
            # subscribers (its publishers filter on them)
            before = len(got["observer"])
            for _ in range(20):
                node.put("episode", SAMPLE)
            deadline = time.monotonic() + TIMEOUT
            while len(got["observer"]) < before + 20 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert len(got["observer"]) == before + 20
        finally:
            node.close()
            for s in subs:
                s.undeclare()
    assert got["daemon"] == []


@pytest.fixture(scope="module")
def fleet_deployment(tmp_path_factory):
    with _router(tmp_path_factory, "ros2-acl-fleet", robots=("ubot1", "ubot2")) as certs:
        yield certs


def test_a_robots_agent_publishes_under_its_own_namespace_only(fleet_deployment):
    got: list[str] = []
    with (_session(fleet_deployment, "agent-ubot1") as agent, _session(fleet_deployment, "observer") as observer):
        sub = observer.declare_subscriber("0/**", lambda sample: got.append(str(sample.key_expr)))
        own = Ros2Node.declare(agent, Ros2Options(), "ubot1")
        other = Ros2Node.declare(agent, Ros2Options(), "ubot2")  # speaking for another robot
        try:
            _put_until(lambda: sum(k.startswith("0/ubot1/") for k in got) >= 20, own, other)
            assert sum(k.startswith("0/ubot1/") for k in got) >= 20
            assert not [k for k in got if not k.startswith("0/ubot1/")]
            tokens = [names.parse_token(str(r.ok.key_expr)) for r in observer.liveliness().get("@ros2_lv/0/**", timeout=2)]
            assert tokens and {t.topic for t in tokens if t.kind == "MP"} == {f"/ubot1/{t}" for t in messages.TOPICS}
        finally:
            own.close()
            other.close()
            sub.undeclare()


@pytest.fixture(scope="module")
def domain_deployment(tmp_path_factory):
    with _router(tmp_path_factory, "ros2-acl-domain", ros_domain=42) as certs:
        yield certs


def test_certs_for_another_ros_domain_let_that_domain_through_and_not_domain_0(domain_deployment):
    """``certs init --ros-domain 42``: an agent on domain 42 reaches an observer (every sample,
    and its tokens); the same agent on domain 0 is dropped at the router."""
    got: list[str] = []
    with (_session(domain_deployment, "agent") as agent, _session(domain_deployment, "observer") as observer):
        subs = [observer.declare_subscriber(f"{d}/**", lambda sample: got.append(str(sample.key_expr)))
                for d in (0, 42)]
        on42 = Ros2Node.declare(agent, Ros2Options(domain=42), "ubot1")
        on0 = Ros2Node.declare(agent, Ros2Options(domain=0), "ubot1")
        try:
            _put_until(lambda: sum(k.startswith("42/") for k in got) >= 20, on0, on42)
            assert sum(k.startswith("42/ubot1/episode/") for k in got) >= 20
            assert [k for k in got if not k.startswith("42/")] == []
            tokens = [names.parse_token(str(r.ok.key_expr)) for r in observer.liveliness().get("@ros2_lv/42/**", timeout=2)]
            assert {t.kind for t in tokens} == {"NN", "MP"} and {t.domain for t in tokens} == {42}
            assert list(observer.liveliness().get("@ros2_lv/0/**", timeout=2)) == []
        finally:
            on0.close()
            on42.close()
            for s in subs:
                s.undeclare()


@pytest.mark.parametrize("value", ["233", "-1"])
def test_certs_init_refuses_a_ros_domain_out_of_range_and_writes_nothing(tmp_path, capsys, value):
    from ersac_hil.cli import main
    assert main(["certs", "init", str(tmp_path / "set"), "--ros-domain", value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--ros-domain" in err[0] and "0..232" in err[0]
    assert not (tmp_path / "set").exists()


def test_the_agents_feed_process_publishes_as_the_agent(fleet_deployment):
    """``agent --ros2 --zenoh-config <the robot's config>``: the node lives in the agent's feed
    process, on a session of its own with the agent's certificate, and the router lets its
    tokens and samples through to an observer as the agent's own."""
    bus = BusConfig("virtual", f"acl-{uuid.uuid4().hex[:8]}")
    robot, got = SimulatedRobot(bus), []
    config = AgentConfig(robot="ubot1", bus=bus, zenoh_connect=(), ros2=Ros2Options(),
                         zenoh_config=str(fleet_deployment.configs["agent-ubot1"]))
    try:
        with (_session(fleet_deployment, "observer") as observer, _session(fleet_deployment, "daemon") as daemon):
            sub = observer.declare_subscriber("0/**", lambda sample: got.append(str(sample.key_expr).split("/")[2]))

            def tokens() -> list[names.Token]:
                return [names.parse_token(str(r.ok.key_expr)) for r in observer.liveliness().get("@ros2_lv/0/**", timeout=2)]
            earlier = {t.zid for t in tokens()}  # a former test's nodes, on their way out

            def node() -> list[names.Token]:
                ours = [t for t in tokens() if t.zid not in earlier]
                return ours if len(ours) == 1 + len(messages.TOPICS) else []
            with AgentService(config) as agent:
                parsed = wait_until(node, what="the node's tokens")
                assert {(t.kind, t.namespace) for t in parsed} == {("NN", "/ubot1"), ("MP", "/ubot1")}
                assert {t.zid for t in parsed} != {str(agent.session.info.zid())}  # not the agent's session
                request = EpisodeRequest("ep-acl1", "bracing", (0.5,), 5)
                [reply] = [EpisodeResult.from_json(r.ok.payload) for r in
                           daemon.get(KeySpace("ubot1").episode_run, payload=request.to_json(), timeout=90)]
                # the feed process runs at niceness +10: on a busy machine it publishes late
                wait_until(lambda: got.count("joint_states") >= round(reply.telemetry["n_cycles"]),
                           what="every joint state at the observer")
            sub.undeclare()
    finally:
        robot.close()
    assert {"joint_states", "imu", "episode"} <= set(got)
