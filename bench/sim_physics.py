"""Physics-only speed of the firmware simulator, per scenario (no CAN, no agent process).

For each scenario one representative episode is stepped through ``Simulator.step`` with the
commands an agent would send (an LQR on the IMU and wheel encoders every period; bracing:
stiff arms, the strike at 0.25 s; lifting: a 3 s two-arm spline). Printed per scenario:
control periods per second, real-time factor, microseconds per period and the share spent in
MuJoCo itself (mj_step1/mj_step2) versus the firmware/scenario Python around it.

    .venv/bin/python bench/sim_physics.py [--repeat 3]

Single-threaded; BLAS pinned to one thread (2-core machine).
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from firmware_sim.plant.linearize import balance_model  # noqa: E402
from firmware_sim.simulator import Simulator  # noqa: E402
from protocol.can.devices import SYNC_PERIOD_S  # noqa: E402

ARM = ("shoulder_left", "elbow_left", "shoulder_right", "elbow_right")
EPISODES = {"idle": 10.0, "bracing": 2.0, "lifting": 6.0}   # simulated seconds


def _gains() -> np.ndarray:
    sim = Simulator()
    sim.reset("idle", 0)
    return balance_model(sim.physics, sim.control_period).lqr_gain(np.diag([0.5, 200.0, 0.5, 5.0]), 1.0)


def _prepare(sim: Simulator, scenario: str) -> None:
    sim.reset(scenario, 1)
    if scenario == "bracing":
        for axis in ARM:
            sim.set_impedance(axis, 250.0, 5.0)
    elif scenario == "lifting":
        for axis in ARM:
            sim.set_impedance(axis, 150.0, 5.0)
        s0, e0 = sim.axis("shoulder_left").position, sim.axis("elbow_left").position
        q = np.array([[s0, e0], [1.6, 1.8], [3.1, 0.1]])
        v = np.zeros_like(q)
        v[1] = (q[2] - q[0]) / 3.0
        for board in ("arm_left", "arm_right"):
            sim.load_spline(board, [0.0, 1.5, 3.0], q, v)
        sim.start_spline()


class _MujocoClock:
    """Wraps mj_step1/mj_step2 to accumulate the time spent inside MuJoCo."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._s1, self._s2 = mujoco.mj_step1, mujoco.mj_step2

    def __enter__(self) -> "_MujocoClock":
        def timed(fn):
            def call(m, d):
                t = time.perf_counter()
                fn(m, d)
                self.seconds += time.perf_counter() - t
            return call
        mujoco.mj_step1, mujoco.mj_step2 = timed(self._s1), timed(self._s2)
        return self

    def __exit__(self, *exc) -> None:
        mujoco.mj_step1, mujoco.mj_step2 = self._s1, self._s2


def run(scenario: str, gains: np.ndarray, clock: bool = False) -> tuple[float, int, float]:
    """(wall seconds, periods, MuJoCo seconds or NaN) for one episode."""
    sim = Simulator()
    _prepare(sim, scenario)
    n = round(EPISODES[scenario] / sim.control_period)
    pitch0, phi0 = sim.imu().pitch, sim.axis("wheel_left").position
    timer = _MujocoClock() if clock else None
    if timer:
        timer.__enter__()
    t0 = time.perf_counter()
    for _ in range(n):
        imu, wl, wr = sim.imu(), sim.axis("wheel_left"), sim.axis("wheel_right")
        x = np.array([0.5 * (wl.position + wr.position) - phi0, imu.pitch - pitch0,
                      0.5 * (wl.velocity + wr.velocity), imu.pitch_rate])
        u = float(np.clip(-(gains @ x)[0], -7.85, 7.85))
        sim.set_wheel_torque(u, u)
        sim.step()
    wall = time.perf_counter() - t0
    if timer:
        timer.__exit__()
    return wall, n, timer.seconds if timer else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="episodes per scenario (best is reported)")
    report(ap.parse_args().repeat)


def report(repeat: int = 3) -> None:
    """Print the physics-only table (one row per scenario)."""
    with threadpool_limits(limits=1):
        gains = _gains()
        print(f"{'scenario':9} {'sim s':>6} {'periods/s':>10} {'RTF':>7} {'us/period':>10} {'MuJoCo %':>9}")
        for scenario in EPISODES:
            best = min(run(scenario, gains)[0] for _ in range(repeat))
            wall, n, mj = run(scenario, gains, clock=True)
            sim_s = n * SYNC_PERIOD_S
            print(f"{scenario:9} {sim_s:6.1f} {n / best:10.0f} {sim_s / best:7.1f} {best / n * 1e6:10.1f}"
                  f" {100 * mj / wall:8.0f}%")
        print("(control period 5 ms, 5 substeps of 1 ms; RTF = simulated / wall time; the agent-side "
              "LQR and telemetry reads are included, CAN is not)")


if __name__ == "__main__":
    main()
