"""The IMU: true values consistent with the physics, seeded Gaussian noise."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.plant import ImuNoise
from firmware_sim.simulator import Simulator


def _run(seed: int, steps: int = 60) -> tuple[np.ndarray, np.ndarray]:
    sim = Simulator()
    sim.reset("idle", seed)
    noisy, true = [], []
    for _ in range(steps):
        sim.step()
        noisy.append(tuple(vars(sim.imu()).values()))
        t = sim.truth
        true.append((t.pitch, t.pitch_rate, t.pitch_acc))
    return np.array(noisy), np.array(true)


def test_at_rest_the_accelerometer_sees_gravity_in_the_body_frame():
    sim = Simulator(imu_noise=ImuNoise(0.0, 0.0, 0.0, 0.0))
    sim.reset("idle", 0)
    imu = sim.imu()
    assert imu.pitch == pytest.approx(sim.physics.body_pitch())
    assert imu.pitch < -0.02                       # arms forward: leans back to balance
    # specific force (0, 0, g) seen from the pitched body frame; the arms start to sag under
    # gravity at t = 0, a small reaction on the body
    assert math.hypot(imu.acc_x, imu.acc_z) == pytest.approx(9.81, abs=0.1)
    assert math.atan2(-imu.acc_x, imu.acc_z) == pytest.approx(imu.pitch, abs=0.03)
    assert imu.pitch_rate == 0.0 and imu.pitch_acc == 0.0


@pytest.mark.parametrize("noise", [ImuNoise(0.0, 0.0, 0.0, 0.0), ImuNoise()])
def test_pitch_acceleration_is_the_derivative_of_the_reported_gyro(noise):
    """The IMU measures rate; the acceleration it reports is the difference of the rates it
    reports, noise included (a real IMU node cannot differentiate the true rate)."""
    sim = Simulator(imu_noise=noise, balance_free=True)
    sim.reset("idle", 0)
    previous = sim.imu().pitch_rate
    for _ in range(80):                            # the passive robot starts to fall
        sim.step()
        imu = sim.imu()
        assert imu.pitch_acc == pytest.approx((imu.pitch_rate - previous) / sim.control_period,
                                              abs=1e-9)
        previous = imu.pitch_rate
    assert abs(previous) > 0.1


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**32 - 1))
def test_noise_is_reproducible_per_seed(seed):
    a, _ = _run(seed, 10)
    b, _ = _run(seed, 10)
    c, _ = _run(seed + 1, 10)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_noise_has_the_documented_spread():
    noise = ImuNoise()
    noisy, true = _run(3, 300)
    err = noisy[:, :3] - true
    sigma_acc = noise.pitch_acc_std(0.005)
    assert sigma_acc == pytest.approx(math.sqrt(2) * noise.pitch_rate / 0.005)   # 1.41 rad/s^2
    for col, sigma in enumerate((noise.pitch, noise.pitch_rate, sigma_acc)):
        assert abs(err[:, col].mean()) < 4 * sigma / math.sqrt(len(err))
        assert err[:, col].std() == pytest.approx(sigma, rel=0.2)
    # a difference of white noise: successive acceleration errors are anti-correlated (-1/2)
    e = err[:, 2]
    assert np.corrcoef(e[1:], e[:-1])[0, 1] == pytest.approx(-0.5, abs=0.15)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**32 - 1), steps=st.integers(60, 140))
def test_noise_drawn_in_blocks_is_the_noise_drawn_sample_by_sample(seed, steps):
    # NOISE_BLOCK samples of noise at a time give every sample the five normals a draw of five
    # per sample gives it, bit for bit (several blocks, and one cut short by a reset)
    import firmware_sim.plant.imu as imu_module

    def readings(block: int) -> list[tuple[float, ...]]:
        saved, imu_module.NOISE_BLOCK = imu_module.NOISE_BLOCK, block
        try:
            sim = Simulator(balance_free=True)
            out = []
            for episode_seed in (seed, seed + 1):
                sim.reset("idle", episode_seed)
                for _ in range(steps):
                    sim.step()
                    out.append(tuple(vars(sim.imu()).values()))
            return out
        finally:
            imu_module.NOISE_BLOCK = saved

    assert np.array(readings(1)).tobytes() == np.array(readings(imu_module.NOISE_BLOCK)).tobytes()
