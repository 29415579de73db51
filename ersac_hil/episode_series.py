"""Per-cycle time series of one episode: the file format (``.npz``) between the agent that
writes it (``ersac-hil agent --record-series DIR``, ``ersac_hil.agent.series``) and the report
that draws it (``ersac_hil.daemon.report``). numpy only.

Arrays (n = cycles; SI units; joints in the order of ``meta["joints"]``: wheel_left,
wheel_right, torso, shoulder_left, elbow_left, shoulder_right, elbow_right):

    t             (n,)    time since the first SYNC of the episode [s]
    pitch, pitch_rate, pitch_acc  (n,)  IMU [rad, rad/s, rad/s^2]
    position, velocity, current, voltage  (n, 7)  measured [rad, rad/s, A, V]
    setpoint      (n, 4)  commanded arm positions (``meta["setpoints"]``: shoulder_left,
                          elbow_left, shoulder_right, elbow_right) [rad], as sent in the RPDOs
    spline        (n,)    the arm boards ran their downloaded spline (START_SPLINE): their
                          setpoint is the spline's, not ``setpoint``
    wheel_torque  (n, 2)  commanded wheel torques (left, right) [N m]
    cable_tension (n, 2)  elbow cable tension (left, right) [N], from the elbow motor current
    status        (n, 5)  status words (``meta["status_devices"]`` order)

``meta`` (JSON): episode id, task, theta, seed, status, failures, cost terms, the result's
telemetry summary (``balance_released_s``: when the balance let go at the strike; ``truth_*``:
the test bench's ground truth), the EMCY events with the index of the cycle they came with,
``strike_acc`` (the task's strike threshold [rad/s^2], or null), the cable's breaking tension
(``cable_breaking_tension_n``, ``cable_strength_range_n``), the column names.
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["EpisodeSeries", "read_series", "write_series"]

_ARRAYS = ("t", "pitch", "pitch_rate", "pitch_acc", "position", "velocity", "current", "voltage",
           "setpoint", "spline", "wheel_torque", "cable_tension", "status")


@dataclass(frozen=True, eq=False)
class EpisodeSeries:
    """One episode's time series (module doc for the arrays and ``meta``)."""

    t: np.ndarray
    pitch: np.ndarray
    pitch_rate: np.ndarray
    pitch_acc: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    current: np.ndarray
    voltage: np.ndarray
    setpoint: np.ndarray
    spline: np.ndarray
    wheel_torque: np.ndarray
    cable_tension: np.ndarray
    status: np.ndarray
    meta: Mapping[str, Any]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def joint(self, name: str) -> int:
        """Column of joint ``name`` in ``position``, ``velocity``, ``current``, ``voltage``."""
        return list(self.meta["joints"]).index(name)

    def setpoint_of(self, name: str) -> np.ndarray:
        """The commanded position of arm joint ``name`` [rad], shape (n,)."""
        return self.setpoint[:, list(self.meta["setpoints"]).index(name)]


def write_series(path: str | Path, series: EpisodeSeries) -> Path:
    """Write ``series`` to ``path`` (``.npz``, compressed; written to a temporary name, then
    renamed, so a reader never sees half a file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, meta=np.array(json.dumps(dict(series.meta))),
                            **{name: getattr(series, name) for name in _ARRAYS})
    tmp.replace(path)
    return path


def read_series(path: str | Path) -> EpisodeSeries:
    """Load a file of :func:`write_series` (``OSError``, ``ValueError``, ``KeyError`` if it is
    not one)."""
    with np.load(Path(path), allow_pickle=False) as data:
        return EpisodeSeries(meta=json.loads(str(data["meta"])), **{name: data[name] for name in _ARRAYS})
