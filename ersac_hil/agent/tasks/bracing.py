"""Bracing for a fall (paper Section 5.1): a swinging mass strikes the robot, the arms take
the ground contact at a stiffness set by theta.

Plan: theta (1,) -> the arm impedance of ``BracingPolicy`` (stiffness and damping of every arm
joint) and the bracing pose, held for the whole episode (T = 2 s, never ends early). The
impedance is written by SDO before NMT start. The balance is released at the strike (no wheel
torque can stop the fall; ``BalanceController``).

Cost terms (``costs``):
    damage       [1]         1.0 if an elbow cable broke (status CABLE_BROKEN in any sample or
                             EMCY 0xFF10), else 0.0
    body_acc_sq  [rad^2/s^3] int alpha_ddot^2 dt, alpha_ddot = IMU pitch acceleration
    arm_power    [J]         consumed electrical energy of the four arm motors,
                             int sum_arm max(I*V, 0) dt
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ersac_hil.agent import costs
from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.policies import ArmImpedance, BracingPolicy
from ersac_hil.agent.robot import RobotParameters
from ersac_hil.agent.tasks.base import Balance, EmcyMark, Task
from ersac_hil.agent.telemetry import Commands, Trace
from protocol.can import objects as obj
from protocol.can.devices import TESTBENCH
from protocol.can.objects import Index, Scenario


@dataclass(frozen=True)
class BracingSetup:
    """One bracing episode: the arm impedance and the pose held for ground contact."""
    impedance: ArmImpedance
    pose: tuple[float, float]


@dataclass(frozen=True)
class BracingTask(Task[BracingSetup]):
    """Attributes:
        policy: theta -> arm impedance, and the bracing pose.
        strike_acc: a pitch acceleration above this [rad/s^2] is the strike; the wheels are
            released (IMU noise is 1.4 rad/s^2, balancing stays below ~5; the padded impactor
            peaks at 70-100).
    """
    policy: BracingPolicy = BracingPolicy()
    strike_acc: float = 30.0
    name = "bracing"
    scenario = Scenario.BRACING

    @classmethod
    def for_robot(cls, robot: RobotParameters) -> "BracingTask":
        return cls(policy=BracingPolicy(robot=robot))

    @property
    def balance(self) -> Balance:
        return Balance(self.policy.pose, 0.0, self.strike_acc)

    def plan(self, theta: Sequence[float]) -> BracingSetup:
        (stiffness,) = theta
        return BracingSetup(self.policy.impedance(stiffness), self.policy.pose)

    def configure(self, bus: AgentBus, setup: BracingSetup) -> Commands:
        bus.apply_impedance(setup.impedance)
        return Commands(arm_left=setup.pose, arm_right=setup.pose)

    def cost_terms(self, trace: Trace, emcy: Sequence[EmcyMark] = ()) -> dict[str, float]:
        return self._checked({"damage": costs.damage(trace, [m.code for m in emcy]),
                              "body_acc_sq": costs.body_acc_sq(trace),
                              "arm_power": costs.arm_power(trace)})

    def ground_truth(self, bus: AgentBus, flags: obj.Status) -> dict[str, float]:
        out = {"truth_impact_momentum_ns": float(bus.read(TESTBENCH, Index.IMPACT_MOMENTUM, 0, obj.MOMENTUM))}
        for sub, side in ((1, "left"), (2, "right")):
            out[f"truth_cable_tension_{side}_n"] = float(bus.read(TESTBENCH, Index.CABLE_TENSION, sub, obj.TENSION))
        return out
