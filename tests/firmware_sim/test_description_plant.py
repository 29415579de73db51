"""The default robot description (protocol/robots/ubot5.toml) is the simulated uBot-5: its
axes are the plant's, with the plant's motor constants, gears, current limits and joint ranges;
the CiA 402 description is the same robot on other drives."""
from __future__ import annotations

import pytest

from firmware_sim.plant import read_motor_params
from firmware_sim.plant.physics import AXES, Physics
from protocol.robot import default_description, load_description
from protocol.robot.model import SHIPPED_EDS_DIR


@pytest.fixture(scope="module")
def physics() -> Physics:
    return Physics.from_xml_path()


def test_the_default_description_is_the_plant(physics):
    description = default_description()
    assert set(description.joints) == set(AXES)
    motors = read_motor_params(physics.model)
    for name in AXES:
        axis, motor = description.axis(name), motors[name]
        assert axis.gear == motor.gear, name
        assert axis.torque_constant == pytest.approx(motor.kt, rel=1e-12), name
        assert axis.back_emf == pytest.approx(motor.ke, rel=1e-12), name
        assert axis.resistance == pytest.approx(motor.resistance, rel=1e-12), name
        assert axis.current_limit == pytest.approx(motor.current_limit, rel=1e-12), name
        assert axis.torque_limit == pytest.approx(motor.torque_limit, rel=1e-9), name
        if axis.position_limits is None:
            assert name.startswith("wheel")
        else:
            assert axis.position_limits.as_tuple() == pytest.approx(physics.joint_range(name)), name


@pytest.mark.skipif(not (SHIPPED_EDS_DIR / "cia402_drive.eds").exists(), reason="no CiA 402 drive EDS yet")
def test_the_cia402_description_is_the_same_robot():
    board, cia402 = default_description(), load_description("ubot5-cia402")
    same = ("gear", "torque_constant", "back_emf", "resistance", "position_limits", "velocity_limit",
            "current_limit", "torque_limit", "stiffness_range", "damping_range")
    for name in AXES:
        a, b = board.axis(name), cia402.axis(name)
        assert {f: getattr(a, f) for f in same} == {f: getattr(b, f) for f in same}, name
