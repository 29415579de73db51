"""The simulated CiA 402 drive beyond conformance: the plant's faults, NMT, scenario resets and the
quick-stop options that end in SWITCH ON DISABLED (one backend: this is the drive's behaviour,
the CAN backends are the conformance suite's)."""
from __future__ import annotations

import pytest

from helpers.can_nodes import set_state
from helpers.cia402 import CSP, CST, DRIVES, Bench, scaling
from protocol.can import cia402
from protocol.can.busconfig import BusConfig
from protocol.can.cia402 import Index
from protocol.can.objects import EmcyCode

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def bench():
    import uuid
    b = Bench(BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}"))
    yield b
    b.close()


def test_broken_cable_faults_the_arm_and_stays(bench):
    shoulder, elbow = bench.start("shoulder_left", "elbow_left")
    s = scaling("elbow_left")
    elbow.op_mode = shoulder.op_mode = CSP
    elbow.sdo[Index.IMPEDANCE][1].raw = round(500.0 / cia402.KP_FACTOR)
    shoulder.state = elbow.state = "OPERATION ENABLED"
    start = s.position(elbow.sdo[Index.POSITION_ACTUAL].raw)
    elbow.rpdo[2]["Target position"].raw = s.increments_of(start + 1.0)  # a jerk the cable cannot take
    for _ in range(100):
        bench.cycle(elbow)
        if bench.robot.sim.status.cable_broken_left:
            break
    assert bench.robot.sim.status.cable_broken_left
    assert EmcyCode.CABLE_BROKEN in [e.code for e in elbow.emcy.log]  # sent before the SYNC's TPDOs
    for node in (shoulder, elbow):  # the arm goes limp: both of its drives
        node.check_statusword()
        assert node.state == "FAULT"
        assert node.sdo[Index.ERROR_CODE].raw == EmcyCode.CABLE_BROKEN
    elbow.controlword = 0x80  # fault reset: refused, the transmission is gone
    assert elbow.sdo[Index.STATUSWORD].raw & 0x4F == 0x08


def test_quick_stop_ramp_disables_once_stopped(bench):
    (node,) = bench.start("wheel_left")
    node.sdo[Index.QUICK_STOP_OPTION].raw = int(cia402.QuickStopOption.QUICK_STOP_RAMP)
    node.sdo[Index.IMPEDANCE][2].raw = round(0.2 / cia402.KD_FACTOR)
    s = scaling("wheel_left")
    node.op_mode = CST
    node.rpdo[2]["Target torque"].raw = s.per_mille_of_torque(1.0)
    node.state = "OPERATION ENABLED"
    bench.cycle(node, 40)
    assert abs(s.velocity(node.sdo[Index.VELOCITY_ACTUAL].raw)) > 0.05
    node.state = "QUICK STOP ACTIVE"
    states = set()
    for _ in range(2000):
        bench.cycle(node)
        state = node.statusword  # from the TPDOs of this SYNC
        states.add(cia402.State.of(state))
        if cia402.State.of(state) is cia402.State.SWITCH_ON_DISABLED:
            break
    assert cia402.State.SWITCH_ON_DISABLED in states
    assert abs(bench.robot.sim.axis("wheel_left").velocity) < 0.05


def test_leaving_operational_disables(bench):
    (node,) = bench.start("torso")
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    set_state(bench.network, DRIVES, "PRE-OPERATIONAL")
    assert node.sdo[Index.STATUSWORD].raw & 0x4F == 0x40
    assert not bench.robot.sim.axis_controller("torso").status("torso").enabled


def test_scenario_reset_returns_to_switch_on_disabled(bench):
    (node,) = bench.start("torso")
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    bench.robot.reset("bracing", 3)
    assert node.sdo[Index.STATUSWORD].raw & 0x4F == 0x40
    assert node.sdo[Index.MODES_DISPLAY].raw == 0
    assert node.sdo[Index.RATED_CURRENT].raw == round(1000 * scaling("torso").rated_current)
