"""ROS 2 messages from the robot description (``ersac_hil.ros2.messages``)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.telemetry import JOINTS
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
