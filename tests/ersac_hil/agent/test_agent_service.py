"""The agent process end to end: real agent (``ersac-hil agent``), real simulator process
(``python -m firmware_sim``), real Zenoh router and client, loopback CAN hub."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
import uuid

import numpy as np
import pytest

from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.canbus import LoopbackHub
from ersac_hil.zenoh_session import EmbeddedRouter
from helpers.can_nodes import Master
from helpers.timing import PATIENT, PATIENT_AGENT_FLAGS, patient_controllers
from helpers.waiting import wait_until
from protocol.can import cobid
from protocol.can.devices import DEVICES
from protocol.can.busconfig import open_bus
from protocol.zenoh import EpisodeDone, EpisodeRequest, EpisodeResult, ErrorReply, KeySpace

pytestmark = pytest.mark.timeout(120)
ROBOT = "ubot-test"
ROBOT_NAME_GO = "ubot-nobench"
KS = KeySpace(ROBOT)
SENSIBLE_LIFT = (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2)


def start_sim(hub: LoopbackHub) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim", "--bus-interface", "remote",
                             "--bus-channel", hub.url], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line.startswith("simulator:"), line + proc.stderr.read()
    return proc


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=10)


def alive(session) -> list[str]:
    return [str(r.ok.key_expr) for r in session.liveliness().get(KS.agent_alive, timeout=1)
            if r.ok is not None]


def wait_for_agent(session, keys: KeySpace = KS) -> list[str]:
    """Declarations reach a new client asynchronously: a get before the agent's queryable is
    known has no replies. The token is declared after the queryable."""
    return wait_until(lambda: [str(r.ok.key_expr) for r in session.liveliness().get(keys.agent_alive, timeout=1)
                               if r.ok is not None], what="the agent's liveliness token")


def when_sync_flows(bus_config, action, syncs: int = 1) -> threading.Thread:
    """Run ``action`` in a thread as soon as ``syncs`` SYNCs (an episode running) crossed the bus."""
    bus = open_bus(bus_config)

    def watch() -> None:
        try:
            deadline, seen = time.monotonic() + 60, 0
            while time.monotonic() < deadline:
                frame = bus.recv(timeout=1.0)
                seen += frame is not None and frame.arbitration_id == cobid.SYNC
                if seen >= syncs:
                    action()
                    return
        finally:
            bus.shutdown()
    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


class Stack:
    def __init__(self):
        self.hub = LoopbackHub()
        self.router = EmbeddedRouter().start()
        self.sim = start_sim(self.hub)
        master = Master(self.hub.bus_config, DEVICES)
        try:
            patient_controllers(master.nodes.values())
        finally:
            master.close()
        self.agent = subprocess.Popen(
            [sys.executable, "-m", "ersac_hil.cli", "agent", "--robot", ROBOT, "--bus-interface",
             "remote", "--bus-channel", self.hub.url, "--zenoh", self.router.endpoint, *PATIENT_AGENT_FLAGS],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.agent.stdout.readline()
        assert line.startswith("agent ready"), line + self.agent.stderr.read()
        self.session = self.router.open_client()
        assert wait_for_agent(self.session), "agent not visible"
        self.done: list[EpisodeDone] = []
        self.sub = self.session.declare_subscriber(
            KS.episode_done, lambda s: self.done.append(EpisodeDone.from_json(s.payload)))

    def close(self):
        self.sub.undeclare()
        self.session.close()
        stop(self.agent)
        stop(self.sim)
        self.router.close()
        self.hub.close()


@pytest.fixture(scope="module")
def stack():
    s = Stack()
    yield s
    s.close()


def ask(session, payload: bytes, timeout: float = 30.0):
    """One reply: (EpisodeResult, None) or (None, ErrorReply)."""
    replies = list(session.get(KS.episode_run, payload=payload, timeout=timeout))
    assert len(replies) == 1, replies
    reply = replies[0]
    if reply.ok is not None:
        return EpisodeResult.from_json(reply.ok.payload), None
    return None, ErrorReply.from_json(reply.err.payload.to_bytes())


def request(task, theta, seed=0) -> bytes:
    return EpisodeRequest(f"ep-{uuid.uuid4().hex[:10]}", task, theta, seed).to_json()


def test_liveliness_token_is_declared(stack):
    assert wait_for_agent(stack.session) == [KS.agent_alive]


def test_bracing_cost_depends_on_stiffness_and_stiff_arms_get_damaged(stack):
    replies = {theta: [ask(stack.session, request("bracing", (theta,), seed)) for seed in (0, 1, 2)]
               for theta in (0.05, 0.95)}
    for rs in replies.values():
        assert all(r is not None and r.status == "ok" for r, _ in rs), rs
    results = {theta: [r for r, _ in rs] for theta, rs in replies.items()}
    soft = np.array([r.total_cost for r in results[0.05]])
    stiff = np.array([r.total_cost for r in results[0.95]])
    assert abs(stiff.mean() - soft.mean()) > 0.1 * max(abs(stiff.mean()), abs(soft.mean()))
    assert any(r.failed("hardware_damage") for r in results[0.95])
    assert not any(r.failed("hardware_damage") for r in results[0.05])
    # every finished episode is published with its request (just after its reply)
    ids = {r.episode_id for rs in results.values() for r in rs}
    wait_until(lambda: ids <= {d.result.episode_id for d in stack.done}, what="episode/done of every episode")
    assert all(d.robot == ROBOT and d.request.episode_id == d.result.episode_id for d in stack.done)


def test_lifting_with_a_sensible_spline_lifts_the_bottle(stack):
    result, error = ask(stack.session, request("lifting", SENSIBLE_LIFT, seed=3))
    assert error is None and result.status == "ok", (error, result)
    assert not result.failed("bottle_dropped")
    assert result.telemetry["final_bottle_height_m"] > 1.1
    assert result.telemetry["truth_bottle_height_m"] > 1.1


def _raw(obj: dict) -> bytes:
    return json.dumps({"v": 1, "type": "episode_request", **obj}).encode()


INVALID = [
    (_raw({"episode_id": "e2", "task": "bracing", "theta": [0.5, 0.5], "seed": 1}), "expected 1 values"),
    (b'{"v": 1, "type": "episode_request", "episode_id": "e3", "task": "bracing", "theta": [NaN], "seed": 1}',
     "NaN"),
    (_raw({"episode_id": "e4", "task": "bracing", "theta": [1.5], "seed": 1}), "outside [0.0, 1.0]"),
    (_raw({"episode_id": "e5", "task": "lifting", "theta": [3.0, 0.2, 0.0, 2.4, 0.2, 0.2, 0.2], "seed": 1}),
     "velocity limit"),
    (_raw({"episode_id": "e6", "task": "lifting", "theta": [-1.0, 1.0, -0.9, 1.0, 0.5, 0.5, 0.5], "seed": 1}),
     "shoulder reaches -1.002 rad"),  # knots inside the box, the spline overshoots the joint stop
    (b"not json", "not valid JSON"),
    (b"", "not valid JSON"),
]


def test_invalid_requests_are_refused_and_the_agent_stays_ready(stack):
    for payload, needle in INVALID:
        result, error = ask(stack.session, payload)
        assert result is None and error.code == "invalid_request", (payload, result)
        assert needle in error.reason, (payload, error.reason)
    result, error = ask(stack.session, _raw({"episode_id": "e1", "task": "juggling", "theta": [0.5], "seed": 1}))
    assert result is None and error.code == "unknown_task" and "unknown task" in error.reason
    result, error = ask(stack.session, request("bracing", (0.5,), seed=4))
    assert error is None and result.status == "ok"


def test_second_request_while_busy_is_refused(stack):
    first: list = []
    second: list = []
    # the second request goes out once the first episode's SYNCs run on the bus
    watcher = when_sync_flows(stack.hub.bus_config,
                              lambda: second.append(ask(stack.session, request("bracing", (0.5,)))))
    first.append(ask(stack.session, request("lifting", SENSIBLE_LIFT)))
    watcher.join(timeout=60)
    result, error = second[0]
    assert result is None and error.code == "busy"
    assert first[0][0] is not None and first[0][0].status == "ok"


def test_agent_process_stops_cleanly_on_sigterm():
    own = Stack()  # its own agent: the module's stack serves the other tests, in any order
    try:
        own.agent.send_signal(signal.SIGTERM)
        out, err = own.agent.communicate(timeout=10)
        assert own.agent.returncode == 143, err
        assert "agent stopped after" in out and "Traceback" not in err
        wait_until(lambda: not alive(own.session), what="the liveliness token gone after the agent stopped")
    finally:
        own.close()


# python-can-remote's per-client sender thread in the hub raises when its client is killed
@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_killing_the_simulator_mid_episode_is_a_fault():
    with LoopbackHub() as hub, EmbeddedRouter() as router:
        sim = start_sim(hub)
        config = AgentConfig(robot=ROBOT, bus=hub.bus_config, zenoh_connect=(router.endpoint,))
        try:
            with AgentService(config), router.open_client() as session:
                assert wait_for_agent(session)
                # mid-episode: the lock-step SYNC loop runs, the task's spline is downloaded (by
                # SDO after the first cycle: a kill then is an SDO fault, fault_simulator)
                killer = when_sync_flows(hub.bus_config, sim.kill, syncs=3)
                result, error = ask(session, request("lifting", SENSIBLE_LIFT))
                killer.join(timeout=60)
                assert sim.poll() is not None, "the simulator was not killed during the episode"
                assert error is None, error
                assert result.status in ("fault_pdo_timeout", "fault_heartbeat"), result
                assert result.cost_terms == {} and result.total_cost is None
                assert sum(result.fault_counts.values()) >= 1
        finally:
            stop(sim)


def test_without_a_test_bench_the_agent_waits_for_the_go_signal(caplog):
    from firmware_sim.nodes.simrobot import SimulatedRobot
    from protocol.can.devices import ROBOT
    from protocol.can.busconfig import BusConfig

    bus = BusConfig("virtual", f"go-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(bus, devices=ROBOT), EmbeddedRouter() as router:
        # no test bench: not a simulated bench, so real time (agent.safety), with a simulator on
        # a loaded machine behind it: patient timing (this test is about the go signal)
        config = AgentConfig(robot=ROBOT_NAME_GO, bus=bus, zenoh_connect=(router.endpoint,), timing=PATIENT)
        with AgentService(config) as agent, router.open_client() as session:
            keys = KeySpace(ROBOT_NAME_GO)
            wait_for_agent(session, keys)
            replies: list = []
            t = threading.Thread(target=lambda: replies.extend(session.get(
                keys.episode_run, payload=request("bracing", (0.5,)), timeout=60)))
            t.start()
            wait_until(lambda: "no test bench" in caplog.text, what="the agent asking for the go signal")
            assert not replies and t.is_alive()  # waiting for the person who reset the robot
            session.put(keys.agent_go, b"go")
            t.join(timeout=60)
            result = EpisodeResult.from_json(replies[0].ok.payload)
            assert result.status == "ok" and result.telemetry["n_cycles"] == 400
            assert "truth_impact_momentum_ns" not in result.telemetry  # no test bench to ask
            assert agent.episodes == 1

