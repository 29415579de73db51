"""Lock-step never fails on wall time: a simulator or an agent that a loaded machine stalls is
late, not gone (``protocol.can.lockstep``); real time keeps the robot's deadlines.

These tests use the product's default timing on purpose (no ``helpers.timing`` patience): the
stall is the fault under test. The stall itself (SIGSTOP of the simulator process, a silent
agent heartbeat) lasts a fixed time: that is the fault's duration, not a synchronisation.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import uuid

import pytest

from ersac_hil.agent.bus import AgentBus, BusTiming
from ersac_hil.agent.episode import EpisodeRunner
from ersac_hil.agent.telemetry import ACTUATED
from ersac_hil.canbus import LoopbackHub
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.processes import group_killed_on_exit
from helpers.waiting import wait_until
from protocol.can.busconfig import BusConfig
from protocol.can.lockstep import LOCKSTEP_PATIENCE_S
from protocol.can.objects import EmcyCode, Index
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(300)
STALL_S = 1.0
"""Longer than every real-time deadline (TPDO 250 ms, heartbeat 0.6 s, consumer 250 ms), well
within the lock-step patience."""
assert STALL_S < LOCKSTEP_PATIENCE_S


def _request(eid: str) -> EpisodeRequest:
    return EpisodeRequest(eid, "bracing", (0.35,), 7)


def _episode(runner: EpisodeRunner, eid: str, during=None):  # noqa: ANN001
    plan = runner.plan(_request(eid))
    thread = threading.Thread(target=during, daemon=True) if during else None
    if thread:
        thread.start()
    try:
        return runner.run(plan)
    finally:
        if thread:
            thread.join(30)


def test_a_stalled_simulator_is_waited_for_and_the_episode_is_the_same():
    """The simulator process stopped for a second mid-episode (as a loaded machine may
    deschedule it): the lock-step episode is ok and bit for bit the one without the stall."""
    with LoopbackHub() as hub:
        proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "sim", "--bus-interface", "remote",
                                 "--bus-channel", hub.url, "--seed", "3"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                start_new_session=True)
        with group_killed_on_exit(proc):
            assert proc.stdout.readline().startswith("simulator:")
            with AgentBus(hub.bus_config) as bus:  # the defaults: lock-step
                bus.wait_for_nodes(timeout_s=30)
                runner = EpisodeRunner(bus)
                calm = _episode(runner, "calm")
                stalled_at: list[int] = []

                def stall() -> None:
                    start = bus.cycles
                    wait_until(lambda: bus.cycles >= start + 150, what="150 cycles of the episode")
                    os.kill(proc.pid, signal.SIGSTOP)
                    stalled_at.append(bus.cycles)
                    time.sleep(STALL_S)
                    os.kill(proc.pid, signal.SIGCONT)
                stalled = _episode(runner, "stalled", stall)
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
    assert stalled_at, "the simulator was never stopped"
    assert calm.status == "ok", calm.detail
    assert stalled.status == "ok", stalled.detail
    assert stalled.cost_terms == calm.cost_terms and stalled.failures == calm.failures
    assert stalled.telemetry["n_cycles"] == calm.telemetry["n_cycles"]


def test_a_stalled_agent_is_not_lost_by_the_controllers_in_lock_step():
    """The agent's heartbeat silent for a second without SYNC (the agent stalled): no
    controller enters its safe state in lock-step; SYNCs without the heartbeat for longer
    than the consumer time (in SYNC periods) still are a loss."""
    config = BusConfig("virtual", f"ls-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(config)
    try:
        with AgentBus(config) as bus:
            bus.wait_for_nodes(timeout_s=30)
            consumer_s = {n.consumer_timeout() for n in robot.nodes.values() if n.consumer_timeout()}
            assert consumer_s and max(consumer_s) < STALL_S  # the defaults (250 ms)
            bus.nmt_start()
            bus.cycle()
            bus.stop_heartbeat()
            time.sleep(STALL_S)  # the stall
            bus.read("arm_right", Index.STATUS)  # SDO barrier: EMCYs sent before it have arrived
            assert not [e for e in bus.emcy_events() if e.code == EmcyCode.HEARTBEAT_LOST]
            cycles = int(max(consumer_s) / bus.timing.period_s) + 2
            for _ in range(cycles):  # SYNCs go on, the heartbeat does not
                bus.cycle()
            actuated = {d.name for d in ACTUATED}
            wait_until(lambda: actuated <= {e.device for e in bus.emcy_events()
                                            if e.code == EmcyCode.HEARTBEAT_LOST},
                       what="EMCY 0x8130 from every controller")
    finally:
        robot.close()


def test_a_heartbeat_timer_behind_a_fast_lock_step_loses_no_controller():
    """The controllers count the agent's silence in SYNC periods in lock-step (which may run
    faster than real time), and a loaded machine delays the agent's heartbeat timer: with the
    timer's beats a minute apart, SYNCs for seconds of simulated time and longer than the
    consumer time on the wall clock bring no EMCY 0x8130 - the SYNC cycle carries the
    heartbeat every heartbeat period of the simulation's clock."""
    config = BusConfig("virtual", f"ls-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(config)
    try:
        with AgentBus(config) as bus:
            bus.wait_for_nodes(timeout_s=30)
            bus.nmt_start()
            timer = bus._heartbeat
            timer.stop()
            timer._period = 60.0
            timer.start()  # one beat now, the next in a minute
            consumer_s = max(n.consumer_timeout() for n in robot.nodes.values())
            started, first = time.monotonic(), bus.cycles
            # far longer than the consumer time both in SYNC periods and on the wall clock,
            # however fast or slow the machine runs lock-step
            while ((bus.cycles - first) * bus.timing.period_s < 2 * STALL_S
                   or time.monotonic() - started < 2 * consumer_s):
                bus.cycle()
            bus.read("arm_right", Index.STATUS)  # SDO barrier: EMCYs sent before it have arrived
            assert not [e for e in bus.emcy_events() if e.code == EmcyCode.HEARTBEAT_LOST]
    finally:
        robot.close()


def test_real_time_keeps_the_robots_deadlines():
    timing = BusTiming(realtime=True)
    assert (timing.tpdo_wait_s, timing.liveness_s) == (timing.deadline_s, timing.heartbeat_timeout_s)
    lockstep = BusTiming()
    assert lockstep.tpdo_wait_s == lockstep.liveness_s == LOCKSTEP_PATIENCE_S


def _burner() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)


def test_lock_step_episodes_beside_two_busy_processes_pass_at_the_first_attempt():
    config = BusConfig("virtual", f"ls-{uuid.uuid4().hex[:8]}")
    with group_killed_on_exit(_burner()), group_killed_on_exit(_burner()):
        robot = SimulatedRobot(config)
        try:
            with AgentBus(config) as bus:  # the defaults, the controllers' consumer time included
                bus.wait_for_nodes(timeout_s=30)
                runner = EpisodeRunner(bus)
                results = [runner.run(runner.plan(EpisodeRequest(f"busy{i}", "bracing", (0.2 + 0.2 * i,), i)))
                           for i in range(3)]
        finally:
            robot.close()
    assert [r.status for r in results] == ["ok"] * 3, [r.detail for r in results]
