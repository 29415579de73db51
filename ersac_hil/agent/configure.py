"""SDO configuration of the robot before an episode (the I/O edge of the policies).

All values in SI units, scaled with ``protocol.can.objects``; a refusal by a controller
raises ``ConfigRefused`` (with the SDO abort code), a silent node ``SdoTimeout``. The arm boards
are those of the bus's robot description (``AgentBus.layout``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ersac_hil.agent.policies import ArmImpedance, Spline
from protocol.can import objects as obj
from protocol.can.devices import TESTBENCH, Device
from protocol.can.objects import Index, Scenario, spline_position_index, spline_velocity_index

if TYPE_CHECKING:  # the bus calls the board functions here (its drive layer)
    from ersac_hil.agent.bus import AgentBus


def reset_scenario(bus: AgentBus, scenario: Scenario, seed: int) -> None:
    """Test bench: scenario, seed, then the reset command (the test bench confirms the SDO once the
    scenario is in its initial state and every board is back at its power-on defaults)."""
    bus.write(TESTBENCH, Index.SCENARIO, 0, int(scenario))
    bus.write(TESTBENCH, Index.SEED, 0, int(seed))
    bus.write(TESTBENCH, Index.RESET, 0, 1)


def apply_impedance(bus: AgentBus, impedance: ArmImpedance, arms: tuple[Device, ...] | None = None) -> None:
    """Stiffness and damping of (shoulder, elbow) on every arm board (default: both of the bus's
    robot)."""
    for arm in bus.layout.arms if arms is None else arms:
        for sub, (k, d) in enumerate(zip(impedance.stiffness, impedance.damping), start=1):
            bus.write(arm, Index.STIFFNESS, sub, k, obj.STIFFNESS)
            bus.write(arm, Index.DAMPING, sub, d, obj.DAMPING)


def download_spline(bus: AgentBus, arm: Device, spline: Spline) -> None:
    """Knot times, positions and velocities of both axes, then the knot count (the board
    validates and loads the spline when the count is written; START_SPLINE starts it)."""
    for k, t in enumerate(spline.times, start=1):
        bus.write(arm, Index.SPLINE_KNOT_TIME, k, float(t), obj.KNOT_TIME)
        for axis in (1, 2):
            bus.write(arm, spline_position_index(axis), k, float(spline.positions[k - 1, axis - 1]),
                      obj.POSITION)
            bus.write(arm, spline_velocity_index(axis), k, float(spline.velocities[k - 1, axis - 1]),
                      obj.VELOCITY)
    bus.write(arm, Index.SPLINE_KNOT_COUNT, 0, len(spline.times))


def read_truth(bus: AgentBus) -> tuple[dict[str, float], obj.Status]:
    """Test-bench readouts every task has (simulated robots only) and its ground-truth
    status word (for the task's own readouts, ``Task.ground_truth``)."""
    flags = obj.Status(int(bus.read(TESTBENCH, Index.GROUND_TRUTH_FLAGS)))
    return ({"truth_damaged": float(bool(flags & obj.Status.CABLE_BROKEN)),
             "truth_fallen": float(bool(flags & obj.Status.FALLEN))}, flags)
