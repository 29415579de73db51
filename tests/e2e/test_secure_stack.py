"""The secure stack across addresses: TLS with client certificates and access control by role.

One stack for the module (``ersac-hil demo --secure --linger`` code): the router listens on
``tls/127.0.0.2``, the daemon connects from 127.0.0.3 and the agent from 127.0.0.4 (loopback
aliases, ``#bind=``), each with its role's certificate from ``certs init``; the CAN bus
between simulator and agent is a direct link: the simulator listens on ``tls/127.0.0.2`` with
the ``simulator`` role's certificate and the router's access control, the agent's bus
connects to it (from 127.0.0.4 too) with its own. The tests then attach as other identities
from this process.
"""
from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
import zenoh

from ersac_hil.certs import init_certs
from ersac_hil.daemon.clients import LearnerClient, NotPermitted
from ersac_hil.daemon.store import Store
from ersac_hil.demo import DemoConfig, run_demo
from ersac_hil.zenoh_session import (
    ZenohOptions, ZenohSessionError, make_config, open_session, resolve_config, session_scope,
    split_endpoint,
)
from helpers.waiting import wait_until
from protocol.zenoh import ErrorReply, KappaCommand, KeySpace, SelectQuery

pytestmark = pytest.mark.slow  # the whole stack (router, simulator, agent, daemon) over TLS

ROUTER, DAEMON, AGENT = "127.0.0.2", "127.0.0.3", "127.0.0.4"
EPISODES = 3


class Stack:
    def __init__(self, out: Path) -> None:
        self.out = out
        self.lines: list[str] = []
        self.up = threading.Event()
        self.stop = threading.Event()
        self.code: int | None = None
        config = DemoConfig(episodes=EPISODES, seed=3, out=out, secure=True, linger=True,
                            router_host=ROUTER, daemon_host=DAEMON, agent_host=AGENT)
        self.thread = threading.Thread(target=self._run, args=(config,), daemon=True)
        self.thread.start()

    def _run(self, config: DemoConfig) -> None:
        def say(line: str) -> None:
            self.lines.append(line)
            if "stack up" in line:
                self.up.set()
        try:
            self.code = run_demo(config, self.stop, say)
        finally:
            self.up.set()

    @property
    def info(self) -> dict:
        import json
        return json.loads((self.out / "stack.json").read_text())

    def options(self, role: str) -> ZenohOptions:
        return ZenohOptions(config_file=self.info["configs"][role])

    def client(self, role: str) -> LearnerClient:
        return LearnerClient(KeySpace(self.info["robot"]), self.options(role), timeout_s=10.0)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    s = Stack(tmp_path_factory.mktemp("secure"))
    try:
        assert s.up.wait(240), "the secure stack did not come up"
        assert s.code is None and (s.out / "stack.json").is_file(), "\n".join(s.lines)
        yield s
    finally:
        s.stop.set()
        s.thread.join(60)
    assert not s.thread.is_alive() and s.code == 0, "\n".join(s.lines)


def _sockets_of(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    return inodes


def _ipv4(hex_addr: str) -> tuple[str, int]:
    ip, port = hex_addr.split(":")
    return ".".join(str(int(ip[i:i + 2], 16)) for i in (6, 4, 2, 0)), int(port, 16)


def _peers(pid: int, router: tuple[str, int]) -> set[str]:
    """Local addresses of ``pid``'s established TCP connections to ``router``."""
    inodes, out = _sockets_of(pid), set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        local, remote, state, inode = _ipv4(fields[1]), _ipv4(fields[2]), fields[3], fields[9]
        if state == "01" and remote == router and inode in inodes:
            out.add(local[0])
    return out


def test_learns_over_tls_with_router_daemon_and_agent_on_different_addresses(stack):
    info = stack.info
    protocol, host, port = split_endpoint(info["router"])
    assert (protocol, host) == ("tls", ROUTER)
    with Store(info["db"], readonly=True) as store:
        run = store.runs()[-1]
        assert len(store.ok_episodes(run.run_id)) == EPISODES
    assert _peers(info["pids"]["daemon"], (ROUTER, port)) == {DAEMON}
    assert _peers(info["pids"]["agent"], (ROUTER, port)) == {AGENT}  # its Zenoh session
    protocol, host, can_port = split_endpoint(info["can"].split("@", 1)[1])
    assert (protocol, host) == ("tls", ROUTER) and can_port != port
    assert _peers(info["pids"]["agent"], (ROUTER, can_port)) == {AGENT}  # its CAN bus, to the simulator
    assert _peers(info["pids"]["sim"], (ROUTER, port)) == set()  # the simulator only listens
    assert any(f"{EPISODES} episodes in" in line for line in stack.lines)


def test_plain_tcp_client_cannot_connect(stack):
    _, host, port = split_endpoint(stack.info["router"])
    with pytest.raises(ZenohSessionError):
        open_session(make_config("client", connect=[f"tcp/{host}:{port}"]))


def test_the_simulators_can_listener_admits_only_the_can_roles(stack):
    import can
    info = stack.info
    _, host, can_port = split_endpoint(info["can"].split("@", 1)[1])
    with pytest.raises(can.CanInitializationError):  # no certificate: no link
        can.Bus(interface="zenoh", channel=f"x@tcp/{host}:{can_port}", connect_timeout=0.5)
    observer = can.Bus(interface="zenoh", channel=info["can"], zenoh_config=info["configs"]["observer"])
    try:  # an identity of the CA, but not a CAN role: the listener's access control keeps it deaf
        assert observer.recv(1.0) is None  # the agent's heartbeat (every 100 ms) never reaches it
    finally:
        observer.shutdown()


def test_tls_client_without_a_valid_certificate_cannot_connect(stack, tmp_path):
    info = stack.info
    no_cert = tmp_path / "no_cert.json5"
    no_cert.write_text('{ mode: "client", transport: { link: { tls: { root_ca_certificate: "%s" } } } }'
                       % info["ca"])
    with pytest.raises(ZenohSessionError):
        open_session(resolve_config(ZenohOptions((info["router"],), str(no_cert))))
    other = init_certs(tmp_path / "other-ca", router=(info["router"],))  # right name, wrong CA
    with pytest.raises(ZenohSessionError):
        open_session(resolve_config(ZenohOptions((info["router"],), str(other.configs["operator"]))))


def test_observer_reads_but_cannot_steer_and_operator_sets_kappa(stack):
    with stack.client("observer") as observer, stack.client("operator") as operator:
        before = observer.state()
        assert before.status in ("stopped", "idle", "paused", "running") and before.episode_count >= EPISODES
        with Store(stack.info["db"], readonly=True) as store:
            answered = [a.episode_id for a in store.attempts(before.run_id) if a.cost_terms is not None]
        for reader in (observer, operator):  # the run's history, as a late dashboard asks for it
            assert [e.result.episode_id for e in reader.episodes()] == answered
        observer.put_raw("kappa", KappaCommand(7.5).to_json())  # dropped by the router
        with pytest.raises(NotPermitted, match="observer may not select a policy"):  # its role, at once
            observer.select(SelectQuery(kappa=1.0, adopt=True))
        with pytest.raises(NotPermitted, match="observer may not set kappa"):
            observer.set_kappa(7.5)
        unchecked = LearnerClient(KeySpace(stack.info["robot"]), stack.options("observer"), 10.0, check_role=False)
        with unchecked:  # sent anyway: the router drops it, and the client says so, not "no answer"
            with pytest.raises(NotPermitted, match="not permitted: the router dropped the query"):
                unchecked.select(SelectQuery(kappa=1.0))
        after = operator.set_kappa(-1.25)  # the operator's put arrives and is applied
        assert after.kappa == -1.25 and observer.state().kappa == -1.25
    with Store(stack.info["db"], readonly=True) as store:
        run = store.runs()[-1].run_id
        assert [c.value for c in store.changes(run, "kappa")] == [-1.25]  # never 7.5


def test_observer_cannot_run_episodes_and_a_rogue_queryable_gets_nothing(stack):
    keys = KeySpace(stack.info["robot"])
    asked: list[str] = []
    request = b'{"v":1,"type":"episode_request","episode_id":"probe","task":"bracing","theta":[7],"seed":1}'
    with (session_scope(resolve_config(stack.options("observer"))) as observer,
          session_scope(resolve_config(stack.options("operator"))) as operator,
          session_scope(resolve_config(stack.options("daemon"))) as daemon):
        assert list(observer.get(keys.episode_run, payload=request, timeout=5)) == []
        rogue_zid = str(operator.info.zid())
        rogue = operator.declare_queryable(keys.episode_run, lambda q: asked.append(str(q.key_expr)))
        token = operator.liveliness().declare_token(keys.agent_session(operator.info.zid()))
        try:
            wait_until(lambda: list(daemon.liveliness().get(keys.agent_sessions, timeout=2)))
            replies = list(daemon.get(keys.episode_run, payload=request, timeout=5,
                                      target=zenoh.QueryTarget.ALL,
                                      consolidation=zenoh.ConsolidationMode.NONE))
            sessions = {str(r.ok.key_expr).rsplit("/", 1)[-1]
                        for r in daemon.liveliness().get(keys.agent_sessions, timeout=2) if r.ok}
        finally:
            token.undeclare()
            rogue.undeclare()
    assert len(replies) == 1 and replies[0].err is not None  # the agent refuses theta 7
    assert ErrorReply.from_json(replies[0].err.payload).code == "invalid_request"
    assert str(replies[0].replier_id.zid) in sessions and rogue_zid not in sessions
    assert asked == []  # nothing was ever routed to the operator's queryable
