"""The CiA 402 drive's EDS (``cia402_drive.eds``): what a stock CiA 402 master needs in it, its PDO
layout and the bus load of seven drives and the IMU. (That it is current with
``tools/gen_eds.py`` is ``test_eds.test_committed_eds_files_match_generator``; the drive on the
bus is ``test_conformance_cia402.py``.)"""
from __future__ import annotations

import canopen
import pytest
from canopen.objectdictionary import ODRecord, ODVariable
from canopen.profiles.p402 import BaseNode402, OperationMode

from protocol.can import cia402
from protocol.can.busload import bus_load
from protocol.can.cia402 import Index
from protocol.can.devices import IMU, TESTBENCH, Device, eds_path
from protocol.can.pdo import pdo_maps

AXES = ("wheel_left", "wheel_right", "torso", "shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
DRIVES = tuple(Device(axis, 0x21 + i, "cia402_drive.eds", ("axis",), (axis,)) for i, axis in enumerate(AXES))


def _var(od, index, sub=0) -> ODVariable:
    entry = od[index]
    return entry if isinstance(entry, ODVariable) else entry[sub]


@pytest.fixture(scope="module")
def od():
    return canopen.import_od(str(eds_path("cia402_drive.eds")), 0x23)


def test_device_type_is_a_cia402_servo_drive(od):
    assert od[0x1000].default == 0x00020192
    assert od[0x1000].default & 0xFFFF == 402


def test_profile_objects_present(od):
    required = [0x1000, 0x1001, 0x1016, 0x1017, 0x1018, *range(0x1400, 0x1404), *range(0x1600, 0x1604),
                *range(0x1800, 0x1804), *range(0x1A00, 0x1A04), *(int(i) for i in Index)]
    missing = [hex(i) for i in required if i not in od]
    assert not missing
    assert isinstance(od[Index.IMPEDANCE], ODRecord)
    assert [od[Index.IMPEDANCE][s].name for s in (1, 2)] == ["Impedance gains Kp", "Impedance gains Kd"]


def test_supported_modes_are_csp_and_cst(od):
    modes = od[Index.SUPPORTED_MODES].default
    assert modes & OperationMode.SUPPORTED["CYCLIC SYNCHRONOUS POSITION"]
    assert modes & OperationMode.SUPPORTED["CYCLIC SYNCHRONOUS TORQUE"]
    assert not modes & OperationMode.SUPPORTED["PROFILED POSITION"]
    assert modes == cia402.SUPPORTED_MODES


def test_pdo_layout():
    by = {(p.direction, p.number): p for p in pdo_maps(DRIVES[2])}
    keys = {k: [e.index for e in p.entries] for k, p in by.items()}
    assert keys[("rpdo", 1)] == [Index.CONTROLWORD, Index.MODES_OF_OPERATION]
    assert keys[("rpdo", 2)] == [Index.TARGET_POSITION, Index.TARGET_TORQUE]
    assert keys[("tpdo", 1)] == [Index.STATUSWORD, Index.MODES_DISPLAY]
    assert keys[("tpdo", 2)] == [Index.STATUSWORD, Index.POSITION_ACTUAL]
    assert keys[("tpdo", 3)] == [Index.VELOCITY_ACTUAL, Index.TORQUE_ACTUAL, Index.CURRENT_ACTUAL]
    assert keys[("rpdo", 3)] == keys[("rpdo", 4)] == keys[("tpdo", 4)] == []
    event = {k for k, p in by.items() if p.entries and not p.synchronous}
    assert event == {("rpdo", 1), ("tpdo", 1)}
    assert by[("rpdo", 1)].cob_id == 0x223 and by[("tpdo", 3)].cob_id == 0x3A3


def test_pdo_entries_are_mappable_and_fit_a_frame(od):
    for p in pdo_maps(DRIVES[0]):
        assert p.length <= 8
        for e in p.entries:
            var = _var(od, e.index, e.subindex)
            assert var.pdo_mappable and len(var) == e.bits, e.name
            assert var.readable if p.direction == "tpdo" else var.writable, e.name


def test_unused_pdos_are_disabled(od):
    network = canopen.Network()  # not connected: PDO maps read from the dictionary only
    node = BaseNode402(0x23, od)
    network.add_node(node)
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    enabled = {(m.cob_id, m.enabled) for m in (*node.tpdo.values(), *node.rpdo.values())}
    assert {c for c, on in enabled if on} == {0x223, 0x323, 0x1A3, 0x2A3, 0x3A3}
    assert node.tpdo[1].event_timer == cia402.EVENT_TIMER_MS
    assert not node.tpdo[1].is_periodic and node.tpdo[2].is_periodic


def test_bus_load_of_seven_drives_and_the_imu_within_70_percent():
    load = bus_load(200.0, 1_000_000, DRIVES + (IMU, TESTBENCH))
    per_axis = [i for i in load.items if i.name.startswith("elbow_left ") and "PDO" in i.name]
    assert len([i for i in per_axis if i.per_cycle == 1.0]) == 3  # three cyclic frames per axis
    assert [i.name for i in per_axis if i.per_cycle != 1.0] == ["elbow_left TPDO1 (0x1A5) every 100 ms"]
    assert load.percent <= 70.0
