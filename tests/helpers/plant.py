"""Balancing the simulated plant without the agent, for the scenario tests: the LQR gain of the
linearised model and the state feedback on the simulator's own readings (the agent's balance
loop, over CAN, is ``ersac_hil.agent.lqr``)."""
from __future__ import annotations

import numpy as np

from firmware_sim.plant.linearize import balance_model
from firmware_sim.simulator import Simulator

Q = np.diag([0.5, 200.0, 0.5, 5.0])
"""State weights: wheel angle, pitch, their rates."""
TORQUE_LIMIT = 7.85
"""N m per wheel: the drivers' current limit times the torque constant and gear."""


def balance_gain(scenario: str = "idle") -> np.ndarray:
    """LQR gain (1, 4) of the robot linearised in ``scenario``'s initial pose."""
    sim = Simulator()
    sim.reset(scenario, 0)
    return balance_model(sim.physics, sim.control_period).lqr_gain(Q, 1.0)


class Balancer:
    """State feedback around the pose ``sim`` is in when constructed."""

    def __init__(self, sim: Simulator, gain: np.ndarray) -> None:
        self.sim, self.gain = sim, gain
        self.pitch0, self.phi0 = sim.imu().pitch, sim.axis("wheel_left").position

    def torque(self) -> float:
        """Wheel torque [N m] (both wheels) from the present IMU and wheel readings."""
        imu, wl, wr = self.sim.imu(), self.sim.axis("wheel_left"), self.sim.axis("wheel_right")
        x = np.array([0.5 * (wl.position + wr.position) - self.phi0, imu.pitch - self.pitch0,
                      0.5 * (wl.velocity + wr.velocity), imu.pitch_rate])
        return float(np.clip(-(self.gain @ x)[0], -TORQUE_LIMIT, TORQUE_LIMIT))
