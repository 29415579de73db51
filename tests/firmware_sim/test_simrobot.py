"""The simulated robot through its CAN interface: SDO configuration reaches the firmware,
splines download and run, the test robot resets scenarios, telemetry is deterministic."""
from __future__ import annotations

import pytest
from canopen.sdo import SdoAbortedError

from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import FrameLog, Master, set_state
from protocol.can import cobid
from protocol.can import objects as o
from protocol.can.devices import ARM_LEFT, DEVICES, TESTBENCH, WHEELS
from protocol.can.pdo import cyclic_pdos
from protocol.can.objects import Control, Index, Status
from protocol.can.sdo import RANGE_ABORTS

pytestmark = pytest.mark.timeout(120)

N_TPDO = sum(1 for p in cyclic_pdos() if p.direction == "tpdo")  # per SYNC, whole robot


@pytest.fixture
def rig(can_backend):
    robot = SimulatedRobot(can_backend)
    master = Master(can_backend, DEVICES)
    yield robot, master.network, master.nodes
    master.close()
    robot.close()


def tpdo_log(net) -> FrameLog:
    """Every TPDO frame of the robot, in arrival order."""
    return FrameLog(net, [cobid.tpdo(n, d.node_id) for d in DEVICES for n in (1, 2, 3)])


def sync_and_wait(net, log: FrameLog, expected: int) -> None:
    """One SYNC, then wait for the ``expected`` TPDO frames it makes the robot send."""
    n0 = len(log.frames)
    net.send_message(cobid.SYNC, b"")
    log.wait_for(lambda frames: len(frames) >= n0 + expected, what="the TPDOs of a SYNC")


def send(pdo_map, *raw: int) -> None:
    """Fill an RPDO's entries in map order and transmit it."""
    for var, value in zip(pdo_map.map, raw, strict=True):
        var.raw = value
    pdo_map.transmit()


def reset(nodes, scenario: o.Scenario, seed: int) -> None:
    tb = nodes[TESTBENCH.name].sdo
    tb[Index.SCENARIO].raw = int(scenario)
    tb[Index.SEED].raw = seed
    tb[Index.RESET].raw = 1


def test_stiffness_by_sdo_reaches_the_firmware(rig):
    robot, net, nodes = rig
    arm = nodes[ARM_LEFT.name].sdo
    arm[Index.STIFFNESS][2].raw = o.STIFFNESS.to_raw(250.0)
    assert robot.sim.controller("arm_left").impedance("elbow_left")[0] == pytest.approx(250.0)
    assert arm[Index.STIFFNESS][2].raw == 25000
    with pytest.raises(SdoAbortedError) as exc:
        arm[Index.STIFFNESS][2].raw = 50001
    assert exc.value.code in RANGE_ABORTS
    assert robot.sim.controller("arm_left").impedance("elbow_left")[0] == pytest.approx(250.0)


def test_spline_download_start_and_tracking(rig):
    robot, net, nodes = rig
    reset(nodes, o.Scenario.IDLE, 1)
    arm = nodes[ARM_LEFT.name]
    for sub in (1, 2):
        arm.sdo[Index.STIFFNESS][sub].raw = o.STIFFNESS.to_raw(400.0)
        arm.sdo[Index.DAMPING][sub].raw = o.DAMPING.to_raw(8.0)
    q0 = robot.sim.axis("shoulder_left").position
    knots = [(0.0, q0, 0.0), (0.3, q0 + 0.4, 0.0)]
    for k, (t, q, v) in enumerate(knots, start=1):
        arm.sdo[Index.SPLINE_KNOT_TIME][k].raw = o.KNOT_TIME.to_raw(t)
        arm.sdo[o.spline_position_index(1)][k].raw = o.POSITION.to_raw(q)
        arm.sdo[o.spline_velocity_index(1)][k].raw = 0
        elbow = robot.sim.axis("elbow_left").position
        arm.sdo[o.spline_position_index(2)][k].raw = o.POSITION.to_raw(elbow)
        arm.sdo[o.spline_velocity_index(2)][k].raw = 0
    arm.sdo[Index.SPLINE_KNOT_COUNT].raw = 2
    assert robot.sim.controller("arm_left").spline is not None
    arm.rpdo.read(from_od=True)
    set_state(net, DEVICES, "OPERATIONAL")
    rec = tpdo_log(net)
    elbow = o.POSITION.to_raw(robot.sim.axis("elbow_left").position)
    for k in range(120):  # 0.6 s
        word = Control.ENABLE | (Control.START_SPLINE if k >= 1 else Control(0))
        send(arm.rpdo.map[1], o.POSITION.to_raw(q0), elbow, int(word))
        sync_and_wait(net, rec, N_TPDO)
    assert robot.sim.axis("shoulder_left").position == pytest.approx(q0 + 0.4, abs=0.08)
    assert Status(arm.sdo[Index.STATUS].raw) & Status.SPLINE_DONE


def test_invalid_spline_is_refused(rig):
    robot, net, nodes = rig
    arm = nodes[ARM_LEFT.name].sdo
    for k in (1, 2):
        arm[Index.SPLINE_KNOT_TIME][k].raw = 500  # two knots at the same time
    with pytest.raises(SdoAbortedError) as exc:
        arm[Index.SPLINE_KNOT_COUNT].raw = 2
    assert exc.value.code in RANGE_ABORTS
    assert robot.sim.controller("arm_left").spline is None


def test_testbench_reset_selects_scenario_and_seed(rig):
    robot, net, nodes = rig
    reset(nodes, o.Scenario.BRACING, 7)
    assert (robot.sim.scenario, robot.sim.seed) == ("bracing", 7)
    momentum = o.MOMENTUM.from_raw(nodes[TESTBENCH.name].sdo[Index.IMPACT_MOMENTUM].raw)
    assert 6.0 <= momentum <= 22.0
    assert momentum == pytest.approx(robot.sim.truth.impact_momentum, abs=0.01)
    with pytest.raises(SdoAbortedError) as exc:
        nodes[TESTBENCH.name].sdo[Index.SCENARIO].raw = 3
    assert exc.value.code in RANGE_ABORTS


def _episode_frames(rig, seed: int, cycles: int) -> list[tuple[int, bytes]]:
    robot, net, nodes = rig
    net.nmt.state = "PRE-OPERATIONAL"
    reset(nodes, o.Scenario.BRACING, seed)
    nodes[ARM_LEFT.name].sdo[Index.STIFFNESS][2].raw = 20000
    set_state(net, DEVICES, "OPERATIONAL")
    rec = tpdo_log(net)
    wheels = nodes[WHEELS.name]
    wheels.rpdo.read(from_od=True)
    for k in range(cycles):
        send(wheels.rpdo.map[1], (k * 37) % 2000 - 1000, (k * 53) % 2000 - 1000, int(Control.ENABLE))
        sync_and_wait(net, rec, N_TPDO)
    rec.close()
    return rec.frames


def test_same_seed_same_commands_bit_identical_telemetry(rig):
    a = _episode_frames(rig, seed=5, cycles=80)
    b = _episode_frames(rig, seed=5, cycles=80)
    per_cob = lambda frames: {c: [d for cc, d in frames if cc == c] for c, _ in frames}  # noqa: E731
    assert per_cob(a) == per_cob(b)
    c = _episode_frames(rig, seed=6, cycles=80)
    assert per_cob(a) != per_cob(c)


def test_actual_values_by_sdo_are_live_before_any_sync(rig):
    robot, net, nodes = rig
    reset(nodes, o.Scenario.BRACING, 2)
    arm = nodes[ARM_LEFT.name].sdo
    shoulder = o.POSITION.from_raw(arm[Index.POSITION][1].raw)
    assert shoulder == pytest.approx(robot.sim.axis("shoulder_left").position, abs=2e-4)
    assert shoulder != 0.0
    pitch = o.PITCH.from_raw(nodes["imu"].sdo[Index.PITCH].raw)
    assert pitch == pytest.approx(robot.sim.imu().pitch, abs=2e-4)


def test_setpoint_sent_with_the_enabling_rpdo_takes_effect(rig):
    robot, net, nodes = rig
    reset(nodes, o.Scenario.IDLE, 1)
    arm = nodes[ARM_LEFT.name]
    arm.rpdo.read(from_od=True)
    set_state(net, DEVICES, "OPERATIONAL")
    target = robot.sim.axis("shoulder_left").position + 0.3
    elbow = o.POSITION.to_raw(robot.sim.axis("elbow_left").position)
    rec = tpdo_log(net)
    send(arm.rpdo.map[1], o.POSITION.to_raw(target), elbow, int(Control.ENABLE))
    sync_and_wait(net, rec, N_TPDO)
    assert robot.sim.controller("arm_left").setpoint("shoulder_left") == pytest.approx(target, abs=1e-3)


def _physics_steps(answers: list[float], until: float, period: float = 0.005) -> list[float]:
    """When the real-time physics thread steps (``realtime_schedule``), SYNCs answered at
    ``answers`` (s), until ``until``: the thread's loop, woken by an answer or its clock."""
    from firmware_sim.nodes.simrobot import realtime_schedule
    steps, last, next_t, pending = [], 0.0, 0.0, sorted(answers)
    while True:
        synced = bool(pending) and pending[0] <= next_t
        now = pending.pop(0) if synced else next_t
        if now > until:
            return steps
        step, next_t = realtime_schedule(synced, now, last, next_t, period)
        if step:
            steps.append(now)
            last = now


def test_realtime_physics_steps_right_after_each_sync_answer_and_on_the_clock_without():
    period = 0.005
    # no SYNC: a step every period on the clock
    assert _physics_steps([], 0.0501) == pytest.approx([k * period for k in range(11)])
    # SYNCs every period from 13.3 ms: after the clock's steps, one step per answer, at the answer
    answers = [0.0133 + k * period for k in range(40)]
    steps = _physics_steps(answers, answers[-1])
    locked = [t for t in steps if t >= answers[0]]
    assert locked == pytest.approx(answers)  # no step on the clock in between: none can meet a SYNC
    # the SYNCs stop: the clock takes over 1.5 periods after the last answer, then every period
    after = _physics_steps(answers, answers[-1] + 0.0201)
    assert after[len(steps):] == pytest.approx([answers[-1] + (1.5 + k) * period for k in range(3)])


def test_realtime_holds_a_reset_scenario_at_its_start_until_the_first_sync():
    """Real time: from the test bench's reset to the episode's first SYNC no plant time passes
    (as in lock-step), however long the agent takes to power its drives up; from that SYNC on
    the physics runs again."""
    import uuid

    from helpers.waiting import wait_until
    from protocol.can.busconfig import BusConfig, open_network

    config = BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(config, realtime=True) as robot:
        wait_until(lambda: robot.stats.cycles >= 3, what="the clock's steps before any reset")
        robot.reset("lifting", 0)
        held = robot.stats.held
        wait_until(lambda: robot.stats.held >= held + 5, what="five periods of the clock held")
        assert robot.sim.sim_time == 0.0 and not robot.sim.status.bottle_dropped
        net = open_network(config)
        try:
            net.send_message(cobid.SYNC, b"")
            wait_until(lambda: robot.sim.sim_time > 0.0, what="a step after the first SYNC")
        finally:
            net.disconnect()


def test_realtime_physics_takes_no_second_step_for_a_sync_right_after_a_clock_step():
    period = 0.005
    steps = _physics_steps([0.0101 + k * period for k in range(5)], 0.031)  # the clock stepped at 10 ms
    assert steps[:3] == pytest.approx([0.0, 0.005, 0.010])
    assert steps[3:] == pytest.approx([0.0151, 0.0201, 0.0251, 0.0301])  # the 10.1 ms SYNC: no step
    assert len(steps) == 7  # one step a period all along


def test_realtime_watchdogs_tick_on_the_physics_thread_heartbeats_out_and_the_agents_watched():
    """Real time: no thread per node; the physics thread's ticks send every node's heartbeat
    and catch the agent's silence (EMCY 0x8130 within the consumer time) as the nodes' own
    threads do in lock-step."""
    import threading
    import uuid

    from protocol.can.busconfig import BusConfig, open_network
    from protocol.can.devices import AGENT_NODE_ID
    from protocol.can.objects import EmcyCode

    config = BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(config, realtime=True) as robot:
        assert not [t for t in threading.enumerate() if t.name.startswith("node-")]
        net = open_network(config)
        try:
            beats = FrameLog(net, [cobid.heartbeat(d.node_id) for d in DEVICES])
            beats.wait_for(lambda _: min(beats.counts().values()) >= 2, what="two heartbeats of every node")
            emcy = FrameLog(net, [cobid.emcy(WHEELS.node_id)])
            net.send_message(cobid.heartbeat(AGENT_NODE_ID), b"\x05")  # heard once, then silent
            code = int(EmcyCode.HEARTBEAT_LOST).to_bytes(2, "little")
            emcy.wait_for(lambda frames: any(data[:2] == code for _, data in frames),
                          what="the wheels' EMCY 0x8130 after the agent fell silent")
            assert robot.stats.cycles > 0  # the physics thread stepped all along
        finally:
            net.disconnect()
