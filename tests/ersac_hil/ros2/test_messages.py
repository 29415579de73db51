"""ROS 2 messages from the robot description (``ersac_hil.ros2.messages``)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Telemetry
from ersac_hil.ros2 import messages
from protocol.robot import load_description, shipped_names


@pytest.mark.parametrize("name", shipped_names())
def test_effort_per_amp_is_each_axis_torque_constant_times_gear(name):
    d = load_description(name)
    per_amp = messages.torque_per_amp(d)
    assert per_amp.shape == (len(JOINTS),)
    for joint, value in zip(JOINTS, per_amp):
        axis = d.axis(joint)
        assert value == axis.torque_constant * axis.gear
    assert np.all(np.isfinite(per_amp))


def test_a_joint_without_an_axis_has_no_effort():
    d = load_description("ubot5")
    partial = dataclasses.replace(d, axes=tuple(a for a in d.axes if a.name != "torso"))
    per_amp = messages.torque_per_amp(partial)
    assert math.isnan(per_amp[JOINTS.index("torso")])
    assert np.all(np.isfinite(np.delete(per_amp, JOINTS.index("torso"))))


@settings(max_examples=300, deadline=None)
@given(stamp=st.integers(0, 2**31 * 10**9 - 1), cob_id=st.integers(0, 2**29 - 1), flags=st.integers(0, 63),
       data=st.binary(max_size=8), dlc=st.one_of(st.none(), st.integers(0, 15)))
def test_the_packed_can_frame_is_rosbags_cdr_byte_for_byte(stamp, cob_id, flags, data, dlc):
    dlc = len(data) if dlc is None else dlc
    reference = messages.serialize(messages.can_frame(stamp, cob_id, flags, dlc, data), messages.CAN_FRAME)
    assert messages.can_frame_cdr(stamp, cob_id, flags, dlc, data) == reference
    back = messages.deserialize(reference, messages.CAN_FRAME)
    assert (back.id, back.dlc, bytes(back.data)[:len(data)]) == (cob_id, dlc, data)
    assert (back.is_extended, back.is_rtr, back.is_error) == (bool(flags & 1), bool(flags & 2), bool(flags & 4))


def test_a_burst_of_standard_frames_is_rosbags_cdr_byte_for_byte():
    burst = [(0x80, b""), (0x201, bytes(range(8))), (0x7FF, b"\x01\x02\x03")]
    packed = messages.can_frames_cdr(1_764_600_000_123_456_789, burst)
    assert packed == [messages.serialize(messages.can_frame(1_764_600_000_123_456_789, cob_id, 0, len(data), data),
                                         messages.CAN_FRAME) for cob_id, data in burst]


_any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)  # every NaN payload too
_not_nan = st.floats(allow_nan=False, allow_infinity=True, width=64)
_stamps = st.integers(0, 2**31 * 10**9 - 1)
_N = len(JOINTS)


def _telemetry(position, velocity, current, pitch, rate, acc_x, acc_z):
    return Telemetry(1, tuple(position), tuple(velocity), tuple(current), (0.0,) * len(position), pitch, rate, 0.0,
                     acc_x, acc_z, (0,) * len(STATUS_DEVICES))


@settings(max_examples=300, deadline=None)
@given(stamp=_stamps, position=st.lists(_any_float, min_size=_N, max_size=_N),
       velocity=st.lists(_any_float, min_size=_N, max_size=_N),
       # effort = current x per_amp: a current is a decoded count (never NaN), per_amp NaN for a joint
       # without an axis (a product of two NaNs has either's payload: numpy's loops differ call to call)
       current=st.lists(_not_nan, min_size=_N, max_size=_N),
       per_amp=st.lists(_not_nan | st.just(math.nan), min_size=_N, max_size=_N),
       imu=st.tuples(st.floats(allow_infinity=False), _any_float, _any_float, _any_float))  # sin(inf) raises
def test_the_fast_per_cycle_cdr_is_rosbags_byte_for_byte(stamp, position, velocity, current, per_amp, imu):
    tel = _telemetry(position, velocity, current, *imu)
    with np.errstate(all="ignore"):  # inf x 0
        reference = messages.serialize(messages.joint_state(tel, stamp, np.array(per_amp)), messages.JOINT_STATE)
    assert messages.joint_state_cdr(tel, stamp, per_amp) == reference
    assert messages.joint_state_cdr(tel, stamp, tuple(float(k) for k in np.array(per_amp))) == reference
    assert messages.imu_cdr(tel, stamp) == messages.serialize(messages.imu(tel, stamp), messages.IMU)


@settings(max_examples=50, deadline=None)
@given(stamp=_stamps, n=st.sampled_from([0, 1, _N - 1, _N + 2]), data=st.data())
def test_another_number_of_joints_is_serialized_by_rosbags(stamp, n, data):
    values = [data.draw(st.lists(st.floats(-1e6, 1e6), min_size=n, max_size=n)) for _ in range(3)]
    tel = _telemetry(*values, 0.1, 0.2, 0.3, 9.81)
    per_amp = np.ones(n)
    assert messages.joint_state_cdr(tel, stamp, per_amp) == messages.serialize(
        messages.joint_state(tel, stamp, per_amp), messages.JOINT_STATE)


@pytest.mark.parametrize("template", [messages._joint_state_template, messages._imu_template])
def test_the_templates_stamp_and_fields_are_where_rosbags_puts_them(template):
    t = template()
    assert t.stamp_at == 4  # the Header's stamp first, after the encapsulation header
    spans = sorted((at, at + packer.size) for packer, at in t.fields)
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))  # no two fields overlap
    assert all(at % 8 == 4 for at, _ in spans)  # float64 aligned to 8 in the CDR body


def test_a_template_refuses_markers_it_cannot_find_once():
    with pytest.raises(ValueError, match="not once"):  # the fields' values do not reach the bytes
        messages.CdrTemplate(messages.IMU, lambda stamp, q: messages._imu(stamp, (0.0, 0.0, 0.0, 1.0),
                                                                          (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), (4,))
