"""The time series of the episode the runner ran last (``ersac-hil agent --record-series DIR``).

The SYNC loop keeps every cycle's telemetry and the commands sent with it in memory anyway (the
cost terms are computed from them); with ``--record-series`` the service writes them after the
episode's reply has gone out (never in the loop) to ``DIR/<episode_id>.npz``, ~40 kB for a
2 s bracing episode (file format: ``ersac_hil.episode_series``).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ersac_hil.agent.episode import LastEpisode
from ersac_hil.agent.robot import UBOT, RobotParameters
from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES
from ersac_hil.episode_series import EpisodeSeries
from protocol.can.objects import Control

__all__ = ["ARM_SETPOINTS", "series_of"]

#: Columns of ``EpisodeSeries.setpoint``.
ARM_SETPOINTS: tuple[str, ...] = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")


def series_of(last: LastEpisode, period_s: float, meta: Mapping[str, Any],
              robot: RobotParameters = UBOT) -> EpisodeSeries:
    """The series of ``last`` (``meta`` goes with it, completed by the column names, the
    task's strike threshold and the cable's limits)."""
    samples, commands = last.samples, last.commands
    if len(samples) != len(commands):
        raise ValueError(f"{len(samples)} samples but {len(commands)} commands")
    n = len(samples)

    def col(name: str, width: int) -> np.ndarray:
        return np.array([getattr(s, name) for s in samples], dtype=float).reshape(n, width)

    current = col("current", len(JOINTS))
    elbows = [JOINTS.index("elbow_left"), JOINTS.index("elbow_right")]
    start_spline = int(Control.START_SPLINE)
    return EpisodeSeries(
        t=np.arange(n, dtype=float) * period_s,
        pitch=col("pitch", 1)[:, 0], pitch_rate=col("pitch_rate", 1)[:, 0],
        pitch_acc=col("pitch_acc", 1)[:, 0],
        position=col("position", len(JOINTS)), velocity=col("velocity", len(JOINTS)),
        current=current, voltage=col("voltage", len(JOINTS)),
        setpoint=np.array([c.arm_left + c.arm_right for c in commands], dtype=float).reshape(n, 4),
        spline=np.array([bool(int(c.arm_control) & start_spline) for c in commands], dtype=bool),
        wheel_torque=np.array([c.wheel_torque for c in commands], dtype=float).reshape(n, 2),
        cable_tension=robot.cable_tension(current[:, elbows]),
        status=np.array([s.status for s in samples], dtype=np.int64).reshape(n, len(STATUS_DEVICES)),
        meta={**meta, "joints": list(JOINTS), "status_devices": list(STATUS_DEVICES),
              "setpoints": list(ARM_SETPOINTS), "period_s": period_s,
              "strike_acc": last.plan.task.balance.strike_acc,
              "emcy": [{"code": code, "device": device, "index": index} for code, device, index in last.emcy],
              "cable_breaking_tension_n": robot.cable_breaking_tension,
              "cable_strength_range_n": list(robot.cable_strength_range)})
