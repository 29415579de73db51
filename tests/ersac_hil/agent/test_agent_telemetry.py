"""The agent's PDO scaling against the EDS files: what ``Telemetry.decode`` makes of the
counts of every TPDO entry, and the counts ``Commands.raw`` puts in every RPDO entry, are what
the EDS ``Factor`` of that object says (canopen's own ``decode_phys``/``encode_phys``)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import SIGNED_TYPES
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.agent.layout import default_layout
from ersac_hil.agent.telemetry import ACTUATED, CYCLIC, Commands, Telemetry, TelemetryDecoder
from protocol.can.devices import ARM_LEFT, ARM_RIGHT, IMU, TORSO, WHEELS, object_dictionary
from protocol.can.objects import Control, Index
from protocol.can.pdo import pdo_maps

AXIS_FIELDS = {Index.POSITION: "position", Index.VELOCITY: "velocity", Index.CURRENT: "current",
               Index.VOLTAGE: "voltage"}
IMU_FIELDS = {Index.PITCH: "pitch", Index.PITCH_RATE: "pitch_rate", Index.PITCH_ACCELERATION: "pitch_acc",
              Index.ACCELERATION_X: "acc_x", Index.ACCELERATION_Z: "acc_z"}


def _var(dev, index: int, sub: int) -> ODVariable:
    obj = object_dictionary(dev)[index]
    return obj if isinstance(obj, ODVariable) else obj[sub]


def _counts(var: ODVariable) -> st.SearchStrategy[int]:
    bits = len(var)
    if var.data_type in SIGNED_TYPES:
        return st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    return st.integers(0, (1 << bits) - 1)


TPDO_ENTRIES = [(dev, e.index, e.subindex) for dev in CYCLIC for p in pdo_maps(dev)
                if p.direction == "tpdo" for e in p.entries]


@st.composite
def tpdo_counts(draw) -> dict[str, dict[tuple[int, int], int]]:
    raw: dict[str, dict[tuple[int, int], int]] = {d.name: {} for d in CYCLIC}
    for dev, index, sub in TPDO_ENTRIES:
        raw[dev.name][(index, sub)] = draw(_counts(_var(dev, index, sub)))
    return raw


SYNC_TPDOS = [p for dev in CYCLIC for p in pdo_maps(dev) if p.direction == "tpdo" and p.synchronous]


@settings(max_examples=50, deadline=None)
@given(tpdo_counts(), st.permutations(SYNC_TPDOS))
def test_the_compiled_decoder_gives_decode_bit_for_bit(raw, tpdos):
    # the agent's hot path: the frames' data by COB-ID, maps in any order
    from protocol.can.pdo import pdo_struct
    decoder = TelemetryDecoder(tpdos)
    frames = {p.cob_id: pdo_struct(p).pack(*[raw[p.device][k] for k in p.keys]) for p in tpdos}
    expected, got = Telemetry.decode(7, raw, 0.25), decoder.decode(7, frames, 0.25)
    assert got == expected and got.latency_s == 0.25
    assert [float(v).hex() for v in got.position + got.current] == [float(v).hex() for v in expected.position + expected.current]


@settings(max_examples=50, deadline=None)
@given(tpdo_counts())
def test_telemetry_decodes_with_the_eds_factor(raw):
    t = Telemetry.decode(7, raw)
    for dev in ACTUATED:
        for sub in range(1, len(dev.joints) + 1):
            j = default_layout().joint_index[(dev.name, sub)]
            for index, field in AXIS_FIELDS.items():
                expected = _var(dev, index, sub).decode_phys(raw[dev.name][(index, sub)])
                assert getattr(t, field)[j] == pytest.approx(expected), (dev.name, field, sub)
    for index, field in IMU_FIELDS.items():
        assert getattr(t, field) == pytest.approx(_var(IMU, index, 0).decode_phys(raw[IMU.name][(index, 0)]))


angles = st.floats(-3.0, 3.0, allow_nan=False)


@given(st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0)), angles,
       st.tuples(angles, angles), st.tuples(angles, angles))
def test_commands_encode_with_the_eds_factor(torque, torso, left, right):
    commands = Commands(wheel_torque=torque, torso_position=torso, arm_left=left, arm_right=right)
    si = {(WHEELS.name, Index.TORQUE_COMMAND): torque, (TORSO.name, Index.POSITION_SETPOINT): (torso,),
          (ARM_LEFT.name, Index.POSITION_SETPOINT): left, (ARM_RIGHT.name, Index.POSITION_SETPOINT): right}
    for dev in ACTUATED:
        raw = commands.raw(dev.name)
        rpdo_keys = {(e.index, e.subindex) for p in pdo_maps(dev) if p.direction == "rpdo" for e in p.entries}
        assert set(raw) == rpdo_keys, dev.name
        for (index, sub), count in raw.items():
            if index == Index.CONTROL:
                assert Control(count) & Control.ENABLE
                continue
            var = _var(dev, index, sub)
            value = si[(dev.name, index)][sub - 1]
            expected = var.encode_phys(value)
            lo, hi = -(1 << (len(var) - 1)), (1 << (len(var) - 1)) - 1  # saturation at the type
            assert count == min(max(expected, lo), hi), (dev.name, index, sub, value)


def _rpdos() -> list:
    from protocol.can.pdo import pdo_struct
    return [(dev.name, p.cob_id, pdo_struct(p), p.keys) for dev in ACTUATED for p in pdo_maps(dev)
            if p.direction == "rpdo"]


@settings(max_examples=60)
@given(st.lists(st.tuples(st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0)), st.sampled_from([0.0, 0.3]),
                          st.sampled_from([(0.1, 0.2), (0.1, 0.25)]), st.sampled_from([(0.1, 0.2), (-0.5, 1.0)]),
                          st.sampled_from([Control.ENABLE, Control.ENABLE | Control.START_SPLINE])),
                min_size=1, max_size=6))
def test_command_encoder_packs_what_raw_says_cycle_after_cycle(sequence):
    """Re-used frames (unchanged setpoints) and re-encoded ones alike: the bytes of
    ``Commands.raw`` packed into each RPDO's struct, in the bus's RPDO order."""
    from ersac_hil.agent.telemetry import CommandEncoder
    rpdos = _rpdos()
    encoder = CommandEncoder(rpdos)
    for torque, torso, left, right, arm_control in sequence:
        commands = Commands(wheel_torque=torque, torso_position=torso, arm_left=left, arm_right=right,
                            arm_control=arm_control)
        expected = [(cob_id, layout.pack(*[commands.raw(name)[k] for k in keys]))
                    for name, cob_id, layout, keys in rpdos]
        assert encoder.encode(commands) == expected


def test_command_encoder_refuses_nan_every_time():
    from ersac_hil.agent.telemetry import CommandEncoder
    encoder = CommandEncoder(_rpdos())
    bad = Commands(arm_left=(float("nan"), 0.0))
    for _ in range(2):  # a refused value is never remembered
        with pytest.raises(ValueError):
            encoder.encode(bad)


finite_or_not = st.floats(allow_nan=False) | st.sampled_from([0.0, -0.0, 5e-324, -5e-324, math.inf, -math.inf])


@given(finite_or_not, finite_or_not)
def test_the_wheel_means_are_numpys_to_the_bit(a, b):
    """``mean2`` (the LQR's and the lifting end condition's wheel means), signed zeros included."""
    from ersac_hil.agent.telemetry import mean2
    with np.errstate(over="ignore", invalid="ignore"):
        expected = float(np.mean((a, b)))
    got = mean2(a, b)
    assert got.hex() == expected.hex() or (math.isnan(got) and math.isnan(expected))
    tel = Telemetry(1, (a, b, 0.0, 0.0, 0.0, 0.0, 0.0), (b, a, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0,) * 7, (0.0,) * 7,
                    0.0, 0.0, 0.0, 0.0, 0.0, (0,) * 5)
    assert tel.wheel_position_mean.hex() == got.hex() or math.isnan(got)
    assert tel.wheel_velocity_mean.hex() == mean2(b, a).hex() or math.isnan(got)
