"""What a task is to the episode runner (after dm_control's ``Task``).

A ``Task`` turns theta (validated by the contract) into a plan (pure: checked before anything moves), configures the
robot for it, gives the arm commands of every cycle, says when the episode is over, and turns
the episode's telemetry into the contract's cost terms. The runner owns everything that is the
same for every task: scenario reset, NMT, the SYNC loop with the LQR balance, faults, EMCY and
status flags, the result. It never looks at a task's name.

Call order in one episode (``EpisodeRunner.run``)::

    setup = task.plan(request.theta)              # pure; RequestRefused (theta: the contract's)
    reset_scenario(bus, task.scenario, seed)      # test bench
    commands = task.configure(bus, setup)         # SDO in PRE-OPERATIONAL; first cycle's commands
    end = task.end_condition(setup, period_s)     # fresh per episode (may count cycles)
    tel = bus.cycle(commands)                     # first SYNC
    commands = task.begin(bus, setup, tel, commands)   # the commands of every later cycle
    ... each cycle: LQR wheel torques (balance reference with task.payload_kg(failures)) + the
        task's arm commands; stop when end(tel, n, failures) says why
    terms = task.cost_terms(trace, emcy)          # exactly TASKS[name].term_names
    summary |= task.summary(trace); truth = task.ground_truth(bus, flags)
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.errors import RequestRefused
from ersac_hil.agent.robot import RobotParameters
from ersac_hil.agent.telemetry import Commands, Telemetry, Trace
from protocol.can.objects import Scenario, Status
from protocol.zenoh import TASKS, TaskSpec

Setup = TypeVar("Setup")

EndCondition = Callable[[Telemetry, int, Mapping[str, bool]], "str | None"]
"""Called after every cycle with its telemetry, the number of cycles so far and the failure
flags raised so far (``protocol.zenoh.FAILURE_FLAGS`` names); returns why the episode ends now
(the result's ``detail``), or ``None`` to go on."""


@dataclass(frozen=True)
class EmcyMark:
    """An EMCY of the episode for the cost: its code and the index of the trace sample it
    arrived with (0 = the first cycle)."""
    code: int
    index: int


class UnknownTask(RequestRefused):
    """The agent serves no task of this name."""

    code = "unknown_task"


@dataclass(frozen=True)
class Balance:
    """What the LQR balance needs from a task.

    Attributes:
        pose: (shoulder, elbow) of both arms the balance model is linearised at [rad].
        payload_kg: mass held at the hands [kg].
        strike_acc: release the wheels above this IMU pitch acceleration [rad/s^2] (``None``:
            never; ``BalanceController``).
    """
    pose: tuple[float, float]
    payload_kg: float = 0.0
    strike_acc: float | None = None


def never_ends(tel: Telemetry, cycles: int, failures: Mapping[str, bool]) -> str | None:
    """End condition of a task that always runs its full horizon."""
    return None


class Task(ABC, Generic[Setup]):
    """One task: its scenario on the test bench, its policy and its cost (see the module
    docstring). Subclasses are frozen dataclasses of configuration; per-episode state lives
    in what ``end_condition`` returns, never in the task."""

    name: str
    scenario: Scenario

    @classmethod
    def for_robot(cls, robot: RobotParameters) -> "Task":
        """The default configuration for ``robot`` (its limits and stiffness range)."""
        return cls()

    @property
    def spec(self) -> TaskSpec:
        """The contract of this task (parameter box, term names, horizon)."""
        return TASKS[self.name]

    @property
    @abstractmethod
    def balance(self) -> Balance:
        """The LQR design point and controller settings of this task."""

    @abstractmethod
    def plan(self, theta: Sequence[float]) -> Setup:
        """theta -> what the robot will do (pure). ``theta`` is the request's, validated once by
        the contract (``EpisodeRequest``: ``TaskSpec.check_theta``, shape and bounds); raises
        ``RequestRefused`` (e.g. a trajectory outside the joint limits)."""

    @abstractmethod
    def configure(self, bus: AgentBus, setup: Setup) -> Commands:
        """SDO configuration in PRE-OPERATIONAL; returns the first cycle's commands."""

    def begin(self, bus: AgentBus, setup: Setup, first: Telemetry, commands: Commands) -> Commands:
        """After the first cycle (the measured start state in ``first``): the arm and torso
        commands of every later cycle (the runner adds the wheel torques). Default: unchanged."""
        return commands

    def payload_kg(self, failures: Mapping[str, bool]) -> float:
        """The mass at the hands the balance references now, given the failure flags raised
        so far (default: ``balance.payload_kg`` throughout)."""
        return self.balance.payload_kg

    def end_condition(self, setup: Setup, period_s: float) -> EndCondition:
        """A fresh end condition for one episode. Default: run the whole horizon."""
        return never_ends

    @abstractmethod
    def cost_terms(self, trace: Trace, emcy: Sequence[EmcyMark] = ()) -> dict[str, float]:
        """Every cost term of this task by name, in ``spec.term_names`` order."""

    def summary(self, trace: Trace) -> dict[str, float]:
        """Task-specific telemetry figures for the reply (added to the common ones)."""
        return {}

    def ground_truth(self, bus: AgentBus, flags: Status) -> dict[str, float]:
        """Task-specific test-bench readouts (simulated benches only); ``flags`` is the bench's
        ground-truth status word, already read."""
        return {}

    def _checked(self, terms: dict[str, float]) -> dict[str, float]:
        """``terms`` in contract order; a set of names other than the contract's is a bug."""
        names = self.spec.term_names
        if set(terms) != set(names):
            raise AssertionError(f"cost terms {sorted(terms)} != contract {sorted(names)}")
        return {name: terms[name] for name in names}
