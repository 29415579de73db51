"""A safe run through the real stack: the simulated robot (MuJoCo, CANopen nodes on a virtual
bus), the agent service and a Zenoh router with a client. The e-stop is measured on the
simulator's side, in SYNC periods: the SYNC at which every axis of the robot is disabled,
counted from the SYNC during which the agent learnt of the stop."""
from __future__ import annotations

import subprocess
import sys
import threading
import uuid
from contextlib import contextmanager
from dataclasses import replace

import pytest

from ersac_hil.agent.episode import EpisodeConfig
from ersac_hil.agent.limits import SetpointLimits
from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.zenoh_session import EmbeddedRouter
from firmware_sim.controllers.boards import BOARDS
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import Master
from helpers.timing import PATIENT, patient_controllers
from helpers.waiting import wait_until
from protocol.can import cobid
from protocol.can.busconfig import BusConfig
from protocol.can.devices import DEVICES, ROBOT
from protocol.can.objects import Index
from protocol.zenoh import AgentState, EpisodeRequest, EpisodeResult, ErrorReply, EstopCommand, KeySpace

pytestmark = pytest.mark.timeout(180)
HOLD_AT = 50
"""The SYNC of the episode during which the e-stop is given."""


class SyncWatch:
    """A second SYNC subscriber on the simulator's network, called after the simulated robot
    applied that SYNC's commands and stepped: counts SYNCs, records whether every axis was
    enabled, and can hold the simulator at one SYNC until released."""

    def __init__(self, robot: SimulatedRobot, hold_at: int | None = None, enabled=None) -> None:  # noqa: ANN001
        """``enabled(robot) -> list[bool]``: which axes are driven (default: the boards' axes)."""
        self.robot, self.hold_at = robot, hold_at
        self._enabled = enabled or (lambda r: [r.sim.controller(board).status(axis).enabled
                                               for board, axes in BOARDS.items() for axis in axes])
        self.count = 0
        self.enabled: list[list[bool]] = []
        self.held, self.release = threading.Event(), threading.Event()
        robot.network.subscribe(cobid.SYNC, self._on_sync)

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self.robot.lock:
            self.count += 1
            self.enabled.append(self._enabled(self.robot))
        if self.count == self.hold_at:
            self.held.set()
            self.release.wait(60)

    def close(self) -> None:
        self.release.set()
        self.robot.network.unsubscribe(cobid.SYNC, self._on_sync)


def bench(devices=DEVICES) -> tuple[BusConfig, SimulatedRobot]:
    bus = BusConfig("virtual", f"safety-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(bus, devices=devices)
    master = Master(bus, devices)
    try:
        patient_controllers(master.nodes.values())  # the held SYNC stalls heartbeats too
    finally:
        master.close()
    return bus, robot


def request(task: str, theta, seed: int = 0) -> bytes:
    return EpisodeRequest(f"ep-{uuid.uuid4().hex[:10]}", task, theta, seed).to_json()


def ask(session, keys: KeySpace, payload: bytes, timeout: float = 60.0):
    replies = list(session.get(keys.episode_run, payload=payload, timeout=timeout))
    assert len(replies) == 1, replies
    if replies[0].ok is not None:
        return EpisodeResult.from_json(replies[0].ok.payload), None
    return None, ErrorReply.from_json(replies[0].err.payload.to_bytes())


def agent_state(session, keys: KeySpace) -> AgentState | None:
    for reply in session.get(keys.agent_state, timeout=5):
        if reply.ok is not None:
            return AgentState.from_json(reply.ok.payload)
    return None


@contextmanager
def serving(keys: KeySpace, bus: BusConfig, router: EmbeddedRouter, **config):
    """An agent service on ``bus`` (patient timing) and a client session that sees it."""
    with AgentService(AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), timing=PATIENT,
                                  **config)) as agent, router.open_client() as session:
        wait_for_agent(session, keys)
        yield agent, session


def wait_for_agent(session, keys: KeySpace) -> None:
    wait_until(lambda: [r for r in session.liveliness().get(keys.agent_alive, timeout=1) if r.ok is not None],
               what="the agent's liveliness token")


def test_estop_stops_every_axis_within_two_sync_periods_and_ends_the_episode_stopped():
    keys = KeySpace("ubot-estop")
    bus, robot = bench()
    watch = SyncWatch(robot, hold_at=HOLD_AT)
    try:
        with EmbeddedRouter() as router:
            with serving(keys, bus, router) as (agent, session):
                wait_until(lambda: agent_state(session, keys).phase == "ready",  # once the bench is heard
                           what="a simulated bench, ready without a go")
                replies: list = []
                t = threading.Thread(target=lambda: replies.append(ask(session, keys, request("bracing", (0.5,)))))
                t.start()
                assert watch.held.wait(60), "the episode did not reach its SYNC"
                assert all(watch.enabled[HOLD_AT - 1]), "every axis runs before the stop"
                session.put(keys.agent_estop, EstopCommand(True, "test stop").to_json())
                wait_until(lambda: agent.safety.engaged is not None, what="the agent hearing the e-stop")
                state = agent_state(session, keys)
                assert state.phase == "stopped" and "test stop" in state.detail
                watch.release.set()
                t.join(timeout=60)
                result, error = replies[0]
                assert error is None, error
                assert result.status == "stopped" and "test stop" in result.detail
                assert result.cost_terms == {} and result.total_cost is None  # nothing to learn from
                stopped_at = next(i + 1 for i, row in enumerate(watch.enabled) if not any(row))
                assert HOLD_AT < stopped_at <= HOLD_AT + 2, (stopped_at, watch.enabled[HOLD_AT - 1:])
                assert not any(any(row) for row in watch.enabled[stopped_at - 1:])  # and it stays so

                # stopped until released: refused, a go does not release it
                _, refused = ask(session, keys, request("bracing", (0.5,)))
                assert refused.code == "unavailable" and "e-stop engaged" in refused.reason
                session.put(keys.agent_go, b"go")
                assert agent_state(session, keys).phase == "stopped"
                syncs = watch.count
                session.put(keys.agent_estop, EstopCommand(False, "checked").to_json())
                wait_until(lambda: agent_state(session, keys).phase == "ready", what="the release")
                assert watch.count == syncs  # releasing moves nothing
                result, error = ask(session, keys, request("bracing", (0.5,), seed=1))
                assert error is None and result.status == "ok"
    finally:
        watch.close()
        robot.close()


def test_an_undecodable_estop_put_is_a_stop():
    keys = KeySpace("ubot-estop-garbled")
    bus, robot = bench()
    try:
        with EmbeddedRouter() as router:
            with serving(keys, bus, router) as (agent, session):
                session.put(keys.agent_estop, b"STOP!")
                wait_until(lambda: agent.safety.engaged is not None, what="the e-stop")
                assert "undecodable" in agent.safety.engaged
    finally:
        robot.close()


def test_a_plan_outside_the_limits_is_refused_with_nothing_moved():
    keys = KeySpace("ubot-limits")
    bus, robot = bench()
    watch = SyncWatch(robot)
    tight = replace(SetpointLimits.from_robot(), stiffness=(0.0, 100.0))  # K(0.95) is ~125 N m/rad
    before = {axis: robot.sim.controller("arm_left").impedance(axis) for axis in BOARDS["arm_left"]}
    try:
        with EmbeddedRouter() as router:
            with serving(keys, bus, router, episode=EpisodeConfig(limits=tight)) as (agent, session):
                result, error = ask(session, keys, request("bracing", (0.95,)))
                assert result is None and error.code == "invalid_request"
                assert "plan refused: shoulder stiffness" in error.reason and "[0, 100]" in error.reason
                assert watch.count == 0 and robot.stats.resets == 0  # no SYNC, no reset
                assert {axis: robot.sim.controller("arm_left").impedance(axis)
                        for axis in BOARDS["arm_left"]} == before  # no SDO download either
                for node in robot.nodes.values():  # no RPDO ever reached a node
                    assert node.received(Index.CONTROL) is None
                result, error = ask(session, keys, request("bracing", (0.2,)))  # inside: it runs
                assert error is None and result.status == "ok"
    finally:
        watch.close()
        robot.close()


def test_without_a_test_bench_lockstep_is_refused_and_the_agent_waits_for_go():
    keys = KeySpace("ubot-realbench")
    bus, robot = bench(ROBOT)  # the robot's nodes, no test bench: not a simulated bench
    watch = SyncWatch(robot)
    try:
        with EmbeddedRouter() as router:
            base = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), timing=PATIENT)
            with AgentService(replace(base, pacing="lockstep")), router.open_client() as session:
                wait_for_agent(session, keys)
                _, error = ask(session, keys, request("bracing", (0.5,)))
                assert error.code == "unavailable"
                assert error.reason.startswith("lock-step refused on virtual:") and "test-bench node" in error.reason
                assert watch.count == 0
            keys2 = KeySpace("ubot-realbench2")
            with AgentService(replace(base, robot=keys2.robot)) as agent, router.open_client() as session:
                wait_for_agent(session, keys2)
                state = agent_state(session, keys2)
                assert (state.phase, state.bench, state.pacing) == ("waiting_for_go", "real", "realtime")
                replies: list = []
                t = threading.Thread(target=lambda: replies.append(ask(session, keys2, request("bracing", (0.5,)))))
                t.start()
                wait_until(lambda: agent.safety.waiting, what="the episode waiting for go")
                assert watch.count == 0 and agent_state(session, keys2).phase == "waiting_for_go"
                session.put(keys2.agent_go, b"go")
                t.join(timeout=60)
                result, error = replies[0]
                assert error is None and result.status == "ok"
                assert agent.bus.timing.realtime  # paced by the wall clock
                assert agent_state(session, keys2).phase == "waiting_for_go"  # one episode per go
    finally:
        watch.close()
        robot.close()


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ersac_hil.cli", *args], capture_output=True, text=True,
                          timeout=120)


def test_estop_go_and_state_commands_are_confirmed_by_the_agent():
    keys = KeySpace("ubot-cli")
    bus, robot = bench(ROBOT)
    try:
        with EmbeddedRouter() as router:
            z = ("--robot", keys.robot, "--zenoh", router.endpoint)
            with serving(keys, bus, router) as (agent, session):
                state = cli("state", *z, "--timeout", "1")
                assert state.returncode == 1  # no learner answers
                assert "agent     waiting_for_go (real bench, realtime" in state.stdout
                go = cli("go", *z)
                assert go.returncode == 0 and "agent     ready" in go.stdout, go
                assert agent.safety.armed
                stop = cli("estop", *z, "--reason", "hand on the button")
                assert stop.returncode == 0 and "stopped" in stop.stdout and "hand on the button" in stop.stdout
                assert not agent.safety.armed  # an e-stop clears a go
                go = cli("go", *z)
                assert go.returncode == 1 and "refused: e-stop engaged" in go.stderr
                release = cli("estop", "--release", *z)
                assert release.returncode == 0 and "waiting_for_go" in release.stdout, release
    finally:
        robot.close()


def test_estop_without_an_agent_says_it_was_not_confirmed():
    with EmbeddedRouter() as router:
        stop = cli("estop", "--robot", "nobody", "--zenoh", router.endpoint, "--timeout", "1")
    assert stop.returncode == 1 and "NOT confirmed - stop the robot by hand" in stop.stderr


def test_an_estopped_episode_is_never_stored_as_ok_by_the_daemon(tmp_path):
    import io
    from ersac_hil.daemon.config import DaemonConfig
    from ersac_hil.daemon.service import Daemon
    from ersac_hil.daemon.store import Store
    keys = KeySpace("ubot-estop-daemon")
    bus, robot = bench()
    watch = SyncWatch(robot, hold_at=HOLD_AT)
    db = tmp_path / "run.db"
    try:
        with EmbeddedRouter() as router:
            with serving(keys, bus, router) as (agent, session):
                daemon = Daemon(DaemonConfig(robot=keys.robot, zenoh=(router.endpoint,), db=db, seed=3,
                                             resume="new", episodes=2, max_attempts=2, backoff_s=(0.05, 0.1)),
                                out=io.StringIO())
                daemon.start()
                try:
                    assert watch.held.wait(120), "the daemon's first episode did not run"
                    session.put(keys.agent_estop, EstopCommand(True, "daemon test").to_json())
                    wait_until(lambda: agent.safety.engaged is not None, what="the e-stop")
                    watch.release.set()
                    # stopped, then refused while the e-stop stays engaged: the run waits, paused,
                    # past max_attempts, and is not failed
                    with Store(db, readonly=True) as store:
                        wait_until(lambda: len(store.attempts(daemon.learning.run_id)) > 2, 120,
                                   what="the daemon asking the held robot again")
                    assert daemon.learning.status == "paused" and not daemon.finished.is_set()
                finally:
                    daemon.stop()
        with Store(db, readonly=True) as store:
            (run,) = store.runs()
            attempts = store.attempts(run.run_id)
            assert store.ok_episodes(run.run_id) == [] and store.update_count(run.run_id) == 0
            assert attempts[0].status == "stopped" and "daemon test" in attempts[0].detail
            assert all(a.status != "ok" for a in attempts) and run.status == "running"
    finally:
        watch.close()
        robot.close()


def test_estop_between_episodes_stops_a_robot_someone_left_enabled():
    keys = KeySpace("ubot-estop-idle")
    bus, robot = bench()
    master = Master(bus, DEVICES)  # someone else's master drove the robot and left it on
    try:
        with EmbeddedRouter() as router, serving(keys, bus, router) as (agent, session):
            master.network.nmt.state = "OPERATIONAL"
            wait_until(lambda: all(n.operational for n in robot.nodes.values()), what="the nodes operational")
            session.put(keys.agent_estop, EstopCommand(True, "idle stop").to_json())
            wait_until(lambda: not any(n.operational for n in robot.nodes.values()),
                       what="every node out of OPERATIONAL (boards: no torque)")
            assert agent_state(session, keys).phase == "stopped"
    finally:
        master.close()
        robot.close()


def test_estop_quick_stops_every_cia402_drive_within_two_sync_periods():
    from firmware_sim.nodes.cia402 import DriveApp
    from protocol.can.cia402 import State
    from protocol.robot import load_description
    description = load_description("ubot5-cia402")
    keys = KeySpace("ubot-estop-cia402")
    bus = BusConfig("virtual", f"safety402-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(bus, description=description)
    drives = [n.app for n in robot.nodes.values() if isinstance(n.app, DriveApp)]
    assert len(drives) == 7
    watch = SyncWatch(robot, hold_at=HOLD_AT, enabled=lambda r: [d.state == State.OPERATION_ENABLED for d in drives])
    try:
        with EmbeddedRouter() as router, serving(keys, bus, router, description=description) as (agent, session):
            replies: list = []
            t = threading.Thread(target=lambda: replies.append(ask(session, keys, request("bracing", (0.5,)))))
            t.start()
            assert watch.held.wait(120), "the episode did not reach its SYNC"
            assert all(watch.enabled[HOLD_AT - 1]), "every drive in OPERATION ENABLED before the stop"
            session.put(keys.agent_estop, EstopCommand(True, "cia402 stop").to_json())
            wait_until(lambda: agent.safety.engaged is not None, what="the agent hearing the e-stop")
            watch.release.set()
            t.join(timeout=120)
            result, error = replies[0]
            assert error is None and result.status == "stopped" and result.cost_terms == {}
            stopped_at = next(i + 1 for i, row in enumerate(watch.enabled) if not any(row))
            assert HOLD_AT < stopped_at <= HOLD_AT + 2, (stopped_at, watch.enabled[HOLD_AT - 1:])
            assert {d.state for d in drives} <= {State.QUICK_STOP_ACTIVE, State.SWITCH_ON_DISABLED}
    finally:
        watch.close()
        robot.close()
