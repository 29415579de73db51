"""The agent's CANopen master against the reference nodes, over every available backend."""
from __future__ import annotations

import dataclasses
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.agent.bus import AgentBus, BusTiming
from ersac_hil.agent.errors import (AgentFault, ConfigRefused, HeartbeatLost,
                                    NodeMissing, PdoTimeout)
from ersac_hil.agent.telemetry import ACTUATED, JOINTS, STATUS_DEVICES, Commands
from helpers.can_nodes import heartbeats
from helpers.timing import PATIENCE_S
from helpers.waiting import wait_until
from protocol.can import cobid
from protocol.can import objects as obj
from protocol.can.devices import (AGENT_NODE_ID, ARM_LEFT, ARM_RIGHT, DEVICES, HEARTBEAT_PERIOD_MS, IMU,
                                  TORSO, WHEELS)
from protocol.can.objects import Control, EmcyCode, Index, Status
from protocol.can.sdo import AbortCode

pytestmark = pytest.mark.timeout(60)

i16 = st.integers(-32768, 32767)


def test_nodes_found_and_started(agent_bus):
    agent_bus.wait_for_nodes(DEVICES, timeout_s=PATIENCE_S)  # the fixture waited for the cyclic nodes only
    assert set(agent_bus.nmt_states()) >= {"wheels", "imu", "testbench"}
    assert all(s == "PRE-OPERATIONAL" for s in agent_bus.nmt_states().values())
    agent_bus.nmt_start()
    tel = agent_bus.cycle()
    assert tel.cycle == 1
    assert all(Status(w) & Status.OPERATION_ENABLED for w in tel.status)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(axes=st.lists(st.tuples(i16, i16, i16, i16), min_size=7, max_size=7),
       wheel_pos=st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(-2**31, 2**31 - 1)),
       imu=st.tuples(i16, i16, i16, i16, i16), status=st.integers(0, 0x7FF))
def test_telemetry_decoded_in_si(agent_bus, reference_nodes, axes, wheel_pos, imu, status):
    agent_bus.nmt_start()  # and one cycle: the static nodes set bit 0 on the transition
    agent_bus.cycle()
    nodes = reference_nodes.nodes
    for j, (dev, sub) in enumerate([(WHEELS, 1), (WHEELS, 2), (TORSO, 1), (ARM_LEFT, 1),
                                    (ARM_LEFT, 2), (ARM_RIGHT, 1), (ARM_RIGHT, 2)]):
        pos, vel, cur, volt = axes[j]
        if dev is WHEELS:
            pos = wheel_pos[sub - 1]
        for index, raw in ((Index.POSITION, pos), (Index.VELOCITY, vel), (Index.CURRENT, cur),
                           (Index.VOLTAGE, volt)):
            nodes[dev.name].set_value(index, sub, raw)
    for index, raw in zip((Index.PITCH, Index.PITCH_RATE, Index.PITCH_ACCELERATION,
                           Index.ACCELERATION_X, Index.ACCELERATION_Z), imu):
        nodes[IMU.name].set_value(index, 0, raw)
    for name in STATUS_DEVICES:
        nodes[name].set_value(Index.STATUS, 0, status)
    tel = agent_bus.cycle()
    assert tel.wheel_positions == pytest.approx((wheel_pos[0] * 1e-4, wheel_pos[1] * 1e-4))
    assert tel.position[JOINTS.index("elbow_right")] == pytest.approx(axes[6][0] * 1e-4)
    assert tel.arm_velocities("left") == pytest.approx((axes[3][1] * 1e-3, axes[4][1] * 1e-3))
    assert tel.current == pytest.approx(tuple(a[2] * 1e-3 for a in axes))
    assert tel.voltage == pytest.approx(tuple(a[3] * 1e-3 for a in axes))
    assert (tel.pitch, tel.pitch_rate, tel.pitch_acc, tel.acc_x, tel.acc_z) == pytest.approx(
        (imu[0] * 1e-4, imu[1] * 1e-3, imu[2] * 0.1, imu[3] * 0.01, imu[4] * 0.01))
    assert tel.status_of("imu") == Status(status)


def test_commands_take_effect_at_sync(agent_bus, reference_nodes):
    agent_bus.nmt_start()
    cmd = Commands(wheel_torque=(1.234, -0.5), torso_position=0.25, arm_left=(0.5, 1.0),
                   arm_right=(-0.3, 0.2), arm_control=Control.ENABLE | Control.START_SPLINE)
    agent_bus.cycle(cmd)
    nodes = reference_nodes.nodes
    assert nodes["wheels"].value(Index.TORQUE_COMMAND, 1) == 1234
    assert nodes["wheels"].value(Index.TORQUE_COMMAND, 2) == -500
    assert nodes["torso"].value(Index.POSITION_SETPOINT, 1) == 2500
    assert nodes["arm_left"].value(Index.POSITION_SETPOINT, 2) == 10000
    assert nodes["arm_right"].value(Index.POSITION_SETPOINT, 1) == -3000
    assert nodes["arm_right"].value(Index.CONTROL, 0) == int(Control.ENABLE | Control.START_SPLINE)
    assert nodes["wheels"].value(Index.CONTROL, 0) == int(Control.ENABLE)
    agent_bus.cycle()  # None repeats the last commands
    assert nodes["wheels"].value(Index.TORQUE_COMMAND, 1) == 1234


def test_no_telemetry_when_preoperational(agent_bus):
    agent_bus.nmt_start()
    agent_bus.cycle()
    agent_bus.nmt_preop()
    with pytest.raises(PdoTimeout) as exc:
        agent_bus.cycle()
    assert "imu" in str(exc.value) and exc.value.status == "fault_pdo_timeout"


def test_missing_tpdo_is_a_timeout_naming_the_node(agent_bus, reference_nodes):
    # a node whose heartbeat is not stale yet when its TPDO is missed: a loaded machine may take
    # longer than the default heartbeat timeout from the removal to the check, which is then
    # (rightly) HeartbeatLost - this test is about the other branch
    agent_bus.timing = dataclasses.replace(agent_bus.timing, heartbeat_timeout_s=PATIENCE_S * 4)
    agent_bus.nmt_start()
    agent_bus.cycle()
    reference_nodes.remove("imu")
    with pytest.raises(PdoTimeout) as exc:
        agent_bus.cycle()
    assert exc.value.missing and all(m.startswith("imu:") for m in exc.value.missing)


def test_silent_node_is_heartbeat_lost(agent_bus, reference_nodes):
    agent_bus.nmt_start()
    agent_bus.cycle()
    reference_nodes.remove("arm_right")
    wait_until(lambda: not agent_bus.present("arm_right"), what="arm_right declared absent")
    assert agent_bus.heartbeat_ages()["arm_right"] > agent_bus.timing.heartbeat_timeout_s
    wait_until(lambda: agent_bus.present("arm_left"), what="arm_left present")
    with pytest.raises(HeartbeatLost) as exc:
        agent_bus.cycle()
    assert exc.value.device == "arm_right" and exc.value.status == "fault_heartbeat"


def test_emcy_collected_with_device_and_cycle(agent_bus, reference_nodes):
    agent_bus.nmt_start()
    agent_bus.cycle()
    reference_nodes.nodes["arm_left"].emergency(EmcyCode.CABLE_BROKEN)
    wait_until(lambda: agent_bus.emcy_count, what="the EMCY")
    (event,) = agent_bus.emcy_events()
    assert (event.device, event.code, event.cycle) == ("arm_left", EmcyCode.CABLE_BROKEN, 1)
    assert agent_bus.emcy_events(since=1) == []


WATCHDOG_MS = 1000
"""The controllers' consumer time in the watchdog test: four times the default (250 ms), so a
loaded machine stalling the agent's heartbeat thread for a few hundred ms does not trip it."""


def test_controllers_enter_safe_state_when_agent_heartbeat_stops(agent_bus, reference_nodes):
    for device in ACTUATED:
        reference_nodes.nodes[device.name].set_value(Index.CONSUMER_HEARTBEAT, 1,
                                                     AGENT_NODE_ID << 16 | WATCHDOG_MS)
    agent_bus.nmt_start()
    agent_bus.cycle()
    # while the agent's heartbeat runs, every controller beats past its consumer time
    beats = heartbeats(agent_bus.net, ACTUATED)
    beats.wait_for(lambda frames: all(beats.count(cobid.heartbeat(d.node_id)) >= WATCHDOG_MS // HEARTBEAT_PERIOD_MS + 2
                                      for d in ACTUATED),
                   what="heartbeats of every controller for longer than the consumer time")
    beats.close()
    agent_bus.read(ARM_RIGHT, Index.STATUS)  # SDO barrier: EMCYs sent before it have arrived
    assert not [e for e in agent_bus.emcy_events() if e.code == EmcyCode.HEARTBEAT_LOST]
    agent_bus.stop_heartbeat()
    actuated = {d.name for d in ACTUATED}
    wait_until(lambda: actuated <= {e.device for e in agent_bus.emcy_events() if e.code == EmcyCode.HEARTBEAT_LOST},
               what="EMCY 0x8130 from every controller")


def test_sdo_write_read_with_scaling_and_typed_refusal(agent_bus):
    raw = agent_bus.write(ARM_LEFT, Index.STIFFNESS, 2, 12.34, obj.STIFFNESS)
    assert raw == 1234
    assert agent_bus.read(ARM_LEFT, Index.STIFFNESS, 2, obj.STIFFNESS) == pytest.approx(12.34)
    agent_bus.write("testbench", Index.SEED, 0, 4_000_000_000)
    assert agent_bus.read("testbench", Index.SEED) == 4_000_000_000
    with pytest.raises(ConfigRefused) as exc:
        agent_bus.write(ARM_LEFT, Index.STIFFNESS, 1, 600.0, obj.STIFFNESS)  # EDS max 500
    assert exc.value.abort_code == AbortCode.VALUE_TOO_HIGH
    assert agent_bus.read(ARM_LEFT, Index.STIFFNESS, 1, obj.STIFFNESS) != 600.0


def test_realtime_mode_paces_sync_by_the_wall_clock(reference_nodes, can_backend):
    timing = BusTiming(period_s=0.005, realtime=True)
    with AgentBus(can_backend, timing=timing) as bus:
        bus.wait_for_nodes(timeout_s=PATIENCE_S)
        bus.nmt_start()
        t0 = time.perf_counter()
        for _ in range(41):
            bus.cycle()
        elapsed = time.perf_counter() - t0
        assert elapsed >= 40 * timing.period_s  # 40 periods between the first and the last SYNC
        before = bus.overruns
        time.sleep(10 * timing.period_s)  # the caller misses ten slots
        bus.cycle()
        assert bus.overruns >= before + 1  # the late cycle counts as an overrun


def test_missing_nodes_reported(can_backend):
    with AgentBus(can_backend) as bus:
        with pytest.raises(NodeMissing) as exc:
            bus.wait_for_nodes(timeout_s=0.2)
    assert "wheels" in exc.value.devices and exc.value.status == "fault_simulator"


def test_bench_gone_mid_run_is_a_fault(agent_bus, reference_nodes):
    agent_bus.nmt_start()
    agent_bus.cycle()
    for name in list(reference_nodes.nodes):
        reference_nodes.remove(name)
    with pytest.raises(AgentFault) as exc:
        for _ in range(1000):
            agent_bus.cycle()
    assert isinstance(exc.value, (PdoTimeout, HeartbeatLost))
