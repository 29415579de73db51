"""The body IMU: pitch, pitch rate, pitch angular acceleration and linear acceleration x/z,
with seeded Gaussian noise.

Sampled once per control period (at SYNC):
- ``pitch`` from the IMU frame's orientation (an attitude filter's output, modelled as the
  true pitch plus white noise);
- ``pitch_rate`` = gyro y (body frame), fresh at the end of the period;
- ``pitch_acc`` = (gyro_k - gyro_k-1) / control_period of the *reported* (noisy) gyro samples:
  a MEMS IMU measures rate, not angular acceleration; the IMU node differentiates the rate it
  reports. It is the mean angular acceleration over the period, so short impact spikes inside
  a period are integrated, not missed, and its noise follows from the gyro's:
  sqrt(2) * sigma_rate / control_period (1.4 rad/s^2 at 5 ms), negatively correlated between
  successive samples (an optional extra white term, ``ImuNoise.pitch_acc``, is 0 by default);
- ``acc_x``, ``acc_z`` = the accelerometer (proper acceleration, body frame; +9.81 on z at
  rest) from the last physics substep.

The noise generator is handed in by the simulator (spawned from the scenario seed, the IMU's
alone) and draws exactly five normals per sample whether or not anyone reads it, so telemetry
is bit-identical for the same seed and command sequence. They are drawn ``NOISE_BLOCK`` samples
at a time: a generator's normals come one after the other whatever the size of a draw, so
sample k gets the same five as with a draw of five per sample.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .physics import Physics


@dataclass(frozen=True)
class ImuSample:
    """One IMU reading. pitch (rad, + forward), pitch_rate (rad/s), pitch_acc (rad/s^2),
    acc_x, acc_z (m/s^2, body frame, includes the reaction to gravity)."""

    pitch: float
    pitch_rate: float
    pitch_acc: float
    acc_x: float
    acc_z: float


@dataclass(frozen=True)
class ImuNoise:
    """Standard deviations of the white noise added to each channel (units of ImuSample).

    ``pitch_acc`` is an *extra* white term on the derived angular acceleration; the derivative
    of the noisy gyro already carries sqrt(2) * pitch_rate / control_period (see the module
    docstring), so the default adds nothing.
    """

    pitch: float = 0.002
    pitch_rate: float = 0.005
    pitch_acc: float = 0.0
    acc: float = 0.05

    def pitch_acc_std(self, control_period: float) -> float:
        """Standard deviation of the reported ``pitch_acc`` (rad/s^2) at ``control_period``."""
        return float(np.hypot(np.sqrt(2.0) * self.pitch_rate / control_period, self.pitch_acc))

    def as_array(self) -> np.ndarray:
        return np.array([self.pitch, self.pitch_rate, self.pitch_acc, self.acc, self.acc])


NOISE_BLOCK = 64
"""Samples whose noise is drawn at once."""


class Imu:
    """IMU model bound to one Physics. Call :meth:`reset` after the episode's initial state is
    set and :meth:`sample` once per control period."""

    def __init__(self, physics: Physics, control_period: float, noise: ImuNoise = ImuNoise()) -> None:
        self._physics = physics
        self._period = control_period
        self._sigma = noise.as_array().tolist()
        m = physics.model
        self._gyro_y = int(m.sensor_adr[m.sensor("imu_gyro").id]) + 1
        acc_adr = int(m.sensor_adr[m.sensor("imu_acc").id])
        self._acc_x, self._acc_z = acc_adr, acc_adr + 2
        self._rng = np.random.default_rng(0)
        self._noise: list[float] = []
        self._noise_at = 0
        self._prev_rate = 0.0
        self._prev_noisy_rate = 0.0
        self._true = (0.0, 0.0, 0.0, 0.0, 0.0)
        self.true_pitch = 0.0
        """The noise-free pitch of the last reading (rad; ``truth.pitch`` without building it)."""
        self.latest = ImuSample(*self._true)

    @property
    def truth(self) -> ImuSample:
        """The noise-free values of the last reading (built when asked: rarely)."""
        return ImuSample(*self._true)

    def reset(self, rng: np.random.Generator) -> None:
        """Start of an episode: zero angular-acceleration history, noise stream ``rng``."""
        self._rng = rng
        self._noise, self._noise_at = [], 0
        self._prev_rate = self._prev_noisy_rate = float(self._physics.data.sensordata[self._gyro_y])
        self.sample()

    def sample(self) -> ImuSample:
        """Take the end-of-period reading; updates ``truth`` (noise-free) and ``latest``."""
        sensors = self._physics.data.sensordata
        period = self._period
        rate = float(sensors[self._gyro_y])
        alpha = (rate - self._prev_rate) / period
        self._prev_rate = rate
        pitch, acc_x, acc_z = self._physics.body_pitch(), float(sensors[self._acc_x]), float(sensors[self._acc_z])
        at = self._noise_at
        if at == len(self._noise):
            self._noise, at = self._rng.standard_normal(5 * NOISE_BLOCK).tolist(), 0
        n_pitch, n_rate, n_alpha, n_acc_x, n_acc_z = self._noise[at:at + 5]
        self._noise_at = at + 5
        s_pitch, s_rate, s_alpha, s_acc_x, s_acc_z = self._sigma
        self._true = (pitch, rate, alpha, acc_x, acc_z)
        self.true_pitch = pitch
        noisy_rate = rate + s_rate * n_rate
        noisy_alpha = (noisy_rate - self._prev_noisy_rate) / period + s_alpha * n_alpha
        self._prev_noisy_rate = noisy_rate
        self.latest = ImuSample(pitch + s_pitch * n_pitch, noisy_rate, noisy_alpha,
                                acc_x + s_acc_x * n_acc_x, acc_z + s_acc_z * n_acc_z)
        return self.latest
