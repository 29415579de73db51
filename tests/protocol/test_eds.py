import subprocess
import sys
from pathlib import Path

from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import SIGNED_TYPES

from protocol.can import objects
from protocol.can.devices import ARM_LEFT, DEVICES, IMU, TESTBENCH, WHEELS, object_dictionary
from protocol.can.objects import OBJECTS, WHEEL_POSITION_OBJECT, Index
from protocol.can.pdo import pdo_maps

ROOT = Path(__file__).resolve().parents[2]


def test_committed_eds_files_match_generator():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_eds.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_every_device_has_identity_heartbeat_and_status():
    for dev in DEVICES:
        od = object_dictionary(dev)
        for index in (0x1000, 0x1001, 0x1016, 0x1017, 0x1018, 0x2010):
            assert index in od, (dev.name, hex(index))


def test_pdo_entries_are_mappable_and_fit_a_frame():
    for dev in DEVICES:
        od = object_dictionary(dev)
        for p in pdo_maps(dev):
            assert p.length <= 8
            for e in p.entries:
                var = od[e.index] if isinstance(od[e.index], ODVariable) else od[e.index][e.subindex]
                assert var.pdo_mappable, (dev.name, p.direction, p.number, e.name)
                assert len(var) == e.bits
                if p.direction == "tpdo":
                    assert var.readable
                else:
                    assert var.writable


def test_cob_ids_unique_on_the_bench():
    cobs = [p.cob_id for d in DEVICES for p in pdo_maps(d)]
    assert len(cobs) == len(set(cobs))
    assert len({d.node_id for d in DEVICES}) == len(DEVICES)


def test_protocol_doc_is_current():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_protocol_doc.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, "docs/protocol.md is stale: run python tools/gen_protocol_doc.py"


def _manufacturer_variables(dev):
    """(index, variable) of every manufacturer object of ``dev``, array elements included."""
    for obj in object_dictionary(dev).values():
        if obj.index < 0x2000:
            continue
        if isinstance(obj, ODVariable):
            yield obj.index, obj
        else:
            yield from ((obj.index, obj[sub]) for sub in range(1, len(obj)))


def _spec_of(index):
    """The table entry an object was generated from (per-axis spline arrays share one)."""
    if index in OBJECTS:
        return OBJECTS[index]
    base = Index.SPLINE_POSITION if (index - Index.SPLINE_POSITION) % 2 == 0 else Index.SPLINE_VELOCITY
    return OBJECTS[base]


def test_eds_objects_carry_the_object_table():
    """Type, access, limits and scaling in every EDS are the ones ``protocol.can.objects`` states."""
    seen = set()
    for dev in DEVICES:
        for index, var in _manufacturer_variables(dev):
            spec = _spec_of(index)
            seen.add(spec.index)
            dtype = WHEEL_POSITION_OBJECT.dtype if (dev is WHEELS and index == Index.POSITION) else spec.dtype
            assert var.data_type == dtype, (dev.name, var.name)
            assert (var.access_type, var.pdo_mappable) == (spec.access, spec.pdo), (dev.name, var.name)
            assert (var.min, var.max) == (spec.low, spec.high), (dev.name, var.name)
            assert var.factor == (spec.factor if spec.factor is not None else 1), (dev.name, var.name)
            assert var.unit == spec.unit and var.description == spec.meaning, (dev.name, var.name)
    assert seen == set(OBJECTS), "objects of the table that no device has"


def test_scales_match_the_eds_factor_and_type():
    """Every ``Scale`` constant equals the EDS Factor and integer range of its object."""
    arm, wheels, testbench = (object_dictionary(d) for d in (ARM_LEFT, WHEELS, TESTBENCH))
    imu = object_dictionary(IMU)
    pairs = [(objects.POSITION, arm[Index.POSITION][1]), (objects.WHEEL_POSITION, wheels[Index.POSITION][1]),
             (objects.VELOCITY, arm[Index.VELOCITY][1]), (objects.CURRENT, arm[Index.CURRENT][1]),
             (objects.VOLTAGE, arm[Index.VOLTAGE][1]), (objects.TORQUE, wheels[Index.TORQUE_COMMAND][1]),
             (objects.STIFFNESS, arm[Index.STIFFNESS][1]), (objects.DAMPING, arm[Index.DAMPING][1]),
             (objects.CURRENT_LIMIT, arm[Index.CURRENT_LIMIT][1]),
             (objects.VELOCITY_LIMIT, arm[Index.VELOCITY_LIMIT][1]),
             (objects.KNOT_TIME, arm[Index.SPLINE_KNOT_TIME][1]), (objects.PITCH, imu[Index.PITCH]),
             (objects.PITCH_RATE, imu[Index.PITCH_RATE]), (objects.PITCH_ACCELERATION, imu[Index.PITCH_ACCELERATION]),
             (objects.ACCELERATION, imu[Index.ACCELERATION_X]), (objects.MOMENTUM, testbench[Index.IMPACT_MOMENTUM]),
             (objects.TENSION, testbench[Index.CABLE_TENSION][1]), (objects.HEIGHT, testbench[Index.BOTTLE_HEIGHT]),
             (objects.SIM_TIME, testbench[Index.SIM_TIME])]
    for scale, var in pairs:
        assert (scale.factor, scale.unit) == (var.factor, var.unit), var.name
        assert scale.bits == len(var) and scale.signed == (var.data_type in SIGNED_TYPES), var.name
