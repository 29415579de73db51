"""CiA 402 conformance of the simulated drives (``ubot5-cia402``: one drive per axis over the
MuJoCo plant), with python canopen's stock ``BaseNode402`` as the master, over every CAN backend.

The master side is canopen's own: ``setup_402_state_machine``, the ``state`` and ``op_mode``
properties, ``reset_from_fault``; the test adds what ``BaseNode402`` leaves to the application:
the agent's heartbeat, SYNC and the cyclic RPDO with the targets (lock-step: every SYNC is one
control period of physics, each cycle waits for the drive's TPDOs). The master's timeouts are
made patient (a loaded machine), never its logic; how fast a fault is noticed is measured by
bench/fault_latency.py.
"""
from __future__ import annotations

import math
import time

import pytest
from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoAbortedError

from ersac_hil.canbus.heartbeat import HeartbeatProducer
from helpers.can_nodes import set_state
from helpers.cia402 import CSP, CST, DESCRIPTION, DRIVES, Bench, scaling
from helpers.timing import PATIENCE_S
from helpers.waiting import wait_until
from protocol.can.lockstep import LOCKSTEP_PATIENCE_S
from protocol.can import cia402
from protocol.can.cia402 import Index, State, Statusword
from protocol.can.devices import object_dictionary
from protocol.can.objects import EmcyCode
from protocol.can.sdo import RANGE_ABORTS

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def bench(can_backend):
    b = Bench(can_backend)
    yield b
    b.close()


def test_setup_402_state_machine_accepts_every_drive(bench):
    nodes = bench.start(*bench.nodes)
    for name, node in zip(bench.nodes, nodes):
        assert node.sdo[0x1000].raw == cia402.DEVICE_TYPE, name
        assert 0x6040 in node.rpdo_pointers and 0x6060 in node.rpdo_pointers, name
        assert 0x6041 in node.tpdo_values and 0x6061 in node.tpdo_values, name
        assert node.is_op_mode_supported(CSP) and node.is_op_mode_supported(CST), name
        assert not node.is_op_mode_supported("PROFILED VELOCITY"), name
        assert node.state == "SWITCH ON DISABLED", name


def test_nmt_states_reported(bench):
    for state in ("OPERATIONAL", "STOPPED", "PRE-OPERATIONAL"):
        set_state(bench.network, DRIVES, state)


def test_state_transitions_to_operation_enabled_and_back(bench):
    (node,) = bench.start("torso")
    node.op_mode = CSP
    seen = []
    for state in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED", "SWITCHED ON",
                  "READY TO SWITCH ON", "OPERATION ENABLED", "SWITCH ON DISABLED"):
        node.state = state
        seen.append(node.state)
        assert State.of(node.sdo[Index.STATUSWORD].raw).label == state
    assert seen[-1] == "SWITCH ON DISABLED"
    assert node.sdo[Index.STATUSWORD].raw & Statusword.REMOTE


def test_mode_switch_confirmed_and_unsupported_refused(bench):
    (node,) = bench.start("shoulder_left")
    for mode, code in ((CSP, 8), (CST, 10), (CSP, 8)):
        node.op_mode = mode
        assert node.op_mode == mode
        assert node.sdo[Index.MODES_DISPLAY].raw == code
    with pytest.raises(TypeError):  # BaseNode402 checks 0x6502 first
        node.op_mode = "PROFILED POSITION"
    with pytest.raises(SdoAbortedError) as exc:  # the drive refuses it too
        node.sdo[Index.MODES_OF_OPERATION].raw = 1
    assert exc.value.code in RANGE_ABORTS
    node.rpdo_pointers[0x6060].raw = 3  # profile velocity over the RPDO: not taken
    node.rpdo[1].transmit()
    assert node.sdo[Index.MODES_DISPLAY].raw == 8 and node.op_mode == CSP


def test_csp_target_followed_by_the_joint(bench):
    (node,) = bench.start("torso")
    s = scaling("torso")
    node.op_mode = CSP
    node.sdo[Index.IMPEDANCE][1].raw = round(100.0 / cia402.KP_FACTOR)
    node.sdo[Index.IMPEDANCE][2].raw = round(8.0 / cia402.KD_FACTOR)
    start = s.position(node.sdo[Index.POSITION_ACTUAL].raw)
    target = start + 0.2
    node.rpdo[2]["Target position"].raw = s.increments_of(target)
    node.state = "OPERATION ENABLED"
    for _ in range(400):  # 2 s of simulated time
        bench.cycle(node)
        if abs(s.position(node.tpdo_values[0x6064]) - target) < 0.01:
            break
    reported = s.position(node.tpdo_values[0x6064])
    assert abs(reported - target) < 0.01
    assert abs(bench.robot.sim.axis("torso").position - reported) < 1e-3  # the plant moved
    assert node.statusword & Statusword.DRIVE_FOLLOWS


def test_cst_torque_applied(bench):
    for name in ("wheel_left", "elbow_right"):
        (node,) = bench.start(name)
        s = scaling(name)
        node.op_mode = CST
        node.rpdo[2]["Target torque"].raw = 0
        node.state = "OPERATION ENABLED"
        torque = (0.2 if name.startswith("wheel") else 0.1) * DESCRIPTION.axis(name).torque_limit
        node.rpdo[2]["Target torque"].raw = s.per_mille_of_torque(torque)
        bench.cycle(node, 2)
        measured = s.torque(node.tpdo_values[0x6077])
        assert measured == pytest.approx(torque, abs=0.03 * torque), name
        assert s.current(node.tpdo_values[0x6078]) == pytest.approx(torque / (s.gear * s.rated_torque / s.rated_current),
                                                                    rel=0.05), name
        node.state = "SWITCH ON DISABLED"
        bench.cycle(node, 2)
        assert node.tpdo_values[0x6077] == 0, name  # torque off when not enabled


def test_quick_stop_holds_and_clears_statusword_bit_5(bench):
    (node,) = bench.start("shoulder_right")
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    bench.cycle(node, 5)
    assert node.statusword & Statusword.QUICK_STOP
    node.state = "QUICK STOP ACTIVE"
    assert not node.statusword & Statusword.QUICK_STOP
    s = scaling("shoulder_right")
    held = s.position(node.sdo[Index.POSITION_ACTUAL].raw)
    node.rpdo[2]["Target position"].raw = s.increments_of(held + 0.3)  # ignored while stopped
    bench.cycle(node, 50)
    assert abs(s.position(node.tpdo_values[0x6064]) - held) < 0.02
    node.state = "OPERATION ENABLED"  # transition 16 (option 6: stay in quick stop until told)
    node.state = "QUICK STOP ACTIVE"
    node.state = "SWITCH ON DISABLED"  # transition 12


def test_quick_stop_option_0_disables_at_once(bench):
    (node,) = bench.start("wheel_right")
    node.sdo[Index.QUICK_STOP_OPTION].raw = int(cia402.QuickStopOption.DISABLE_DRIVE)
    with pytest.raises(SdoAbortedError):
        node.sdo[Index.QUICK_STOP_OPTION].raw = 3  # not an option this drive has
    node.op_mode = CST
    node.state = "OPERATION ENABLED"
    node.controlword = cia402.Command.QUICK_STOP.bits
    node.check_statusword()
    assert node.sdo[Index.STATUSWORD].raw & 0x4F == 0x40  # SWITCH ON DISABLED


def test_heartbeat_loss_faults_with_emcy_and_fault_reset(bench):
    (node,) = bench.start("elbow_left")
    node.sdo[0x1016][1].raw = object_dictionary(DRIVES[0])[0x1016][1].default  # the EDS's 250 ms
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    bench.heartbeat.stop()
    # no SYNC comes: a lock-step drive counts the silence as a loss only after the lock-step
    # patience (protocol.can.lockstep); the loaded-machine margin comes on top
    entry = node.emcy.wait(EmcyCode.HEARTBEAT_LOST, timeout=LOCKSTEP_PATIENCE_S + PATIENCE_S)
    assert entry is not None and entry.code == EmcyCode.HEARTBEAT_LOST
    node.check_statusword()
    assert node.state == "FAULT"
    assert node.sdo[Index.ERROR_CODE].raw == EmcyCode.HEARTBEAT_LOST
    bench.cycle(node, 2)
    assert node.tpdo_values[0x6077] == 0  # no torque in FAULT
    bench.heartbeat = HeartbeatProducer(bench.network).start()
    node.TIMEOUT_RESET_FAULT = BaseNode402.TIMEOUT_RESET_FAULT  # its FIXME: always waits it out
    node.reset_from_fault()
    assert node.state == "OPERATION ENABLED"
    assert node.sdo[Index.ERROR_CODE].raw == 0


def test_a_broken_cable_stays_the_error_through_a_sync_driven_heartbeat_loss_and_no_reset_clears_it(bench):
    """What made a fault reset time out after a heartbeat loss with SYNCs flowing: the limp arm
    broke its cable first (EMCY 0xFF10, not resettable) and the heartbeat fault that followed
    overwrote 0x603F. The cable's code stays; the reset leaves the drive in FAULT."""
    (node,) = bench.start("elbow_left")
    node.sdo[0x1016][1].raw = object_dictionary(DRIVES[0])[0x1016][1].default  # the EDS's 250 ms
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    drive = bench.robot.nodes["elbow_left"]
    drive.app.on_failure(EmcyCode.CABLE_BROKEN)  # what the plant's failure event does (SimulatedRobot._step)
    drive.emergency(EmcyCode.CABLE_BROKEN)
    # in the log, not emcy.wait(): that waits for a later EMCY and misses one already dispatched
    wait_until(lambda: any(e.code == EmcyCode.CABLE_BROKEN for e in node.emcy.log), PATIENCE_S,
               what="the broken cable's EMCY")
    bench.heartbeat.stop()
    # SYNC-driven: a loss after 250 ms of wall clock and 50 SYNC periods of silence both
    deadline = time.monotonic() + LOCKSTEP_PATIENCE_S + PATIENCE_S
    while time.monotonic() < deadline and not any(e.code == EmcyCode.HEARTBEAT_LOST for e in node.emcy.log):
        bench.cycle(node)
    assert [e.code for e in node.emcy.log][-2:] == [EmcyCode.CABLE_BROKEN, EmcyCode.HEARTBEAT_LOST]
    assert node.sdo[Index.ERROR_CODE].raw == EmcyCode.CABLE_BROKEN
    bench.heartbeat = HeartbeatProducer(bench.network).start()
    node.TIMEOUT_RESET_FAULT, node.TIMEOUT_SWITCH_STATE_SINGLE = 0.05, 0.2  # it fails whatever the wait
    with pytest.raises(RuntimeError):
        node.reset_from_fault()
    assert State.of(node.sdo[Index.STATUSWORD].raw) is State.FAULT
    assert node.sdo[Index.ERROR_CODE].raw == EmcyCode.CABLE_BROKEN


def test_telemetry_scaled_in_profile_units(bench):
    (node,) = bench.start("shoulder_left")
    s = scaling("shoulder_left")
    assert node.sdo[Index.GEAR_RATIO][1].raw / node.sdo[Index.GEAR_RATIO][2].raw == s.gear
    assert node.sdo[Index.ENCODER_RESOLUTION][1].raw == DESCRIPTION.axis("shoulder_left").encoder_counts
    assert node.sdo[Index.RATED_CURRENT].raw == round(1000 * s.rated_current)
    assert node.sdo[Index.DC_LINK_VOLTAGE].raw == 24000
    plant = bench.robot.sim.axis("shoulder_left").position
    assert math.isclose(s.position(node.sdo[Index.POSITION_ACTUAL].raw), plant, abs_tol=2 * s.rad_per_increment)
