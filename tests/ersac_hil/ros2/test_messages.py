"""ROS 2 messages from the robot description (``ersac_hil.ros2.messages``)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

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
