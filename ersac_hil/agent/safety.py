"""A safe run on hardware: which pacing a bus gets, the e-stop and go latch, the quick stop.

**Simulated bench or real robot.** Lock-step (the next SYNC as soon as the simulator has
answered the last one) is only meaningful against a simulator; a real robot is paced by the
wall clock. The agent decides it in two steps:

1. From the bus configuration, before anything starts: a physical bus - ``socketcan`` on a
   channel that is not ``vcan*``, or any hardware interface of python-can (``pcan``,
   ``kvaser``, ``slcan``...) - is a real robot, whatever answers on it. Only ``virtual``, the
   loopback hub (``remote``), CAN over Zenoh (``zenoh``) and ``vcan*`` may carry a simulator.
2. On such a bus, at every episode: it is a simulated bench only while the simulator's
   test-bench node (node-id 0x7E, scenario reset and ground truth, which no robot has) is
   heard on it. A gateway from one of these interfaces to a real robot has no test bench, so
   it is treated as the robot it is.

Real time is the default everywhere except on a simulated bench (where lock-step stays the
default, as the paper's experiments ran); ``--lockstep`` on a bus that is not a simulated bench
is refused with one line saying why (``pacing``).

**The e-stop** (``Safety``): a put on ``<prefix>/<robot>/agent/estop`` (operator role only)
latches it. The SYNC loop looks at it before every cycle; the next cycle sends the quick-stop
commands (``QuickStop``) with its SYNC, so every axis is stopped within two SYNC periods of the
e-stop reaching the agent (one when it arrives while a cycle waits for its TPDOs, two when it
arrives after the cycle's commands were chosen), and the episode ends ``stopped``. Between
episodes the e-stop sends the profile's idle stop (the boards: NMT pre-operational). While
latched the agent runs no episode (``unavailable``); ``ersac-hil estop --release`` unlatches
it, and where the robot has no test bench it then waits for a new go: a go never releases an
e-stop (a person's "the robot is reset" must not undo another person's stop).

**Go**: without a test bench every episode starts only after a go (``ersac-hil go``, a put on
``agent/go``): the robot was reset by a person who is watching it. A go given before the
episode asks for it is kept for the next episode (one episode per go); an e-stop clears it.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from typing import Protocol

from ersac_hil.agent.errors import RequestRefused
from ersac_hil.agent.telemetry import Commands
from protocol.can.busconfig import BusConfig
from protocol.can.objects import Control

PACINGS = ("auto", "realtime", "lockstep")
"""What the agent was asked for: ``auto`` is the policy of the module docstring."""
SIMULATION_INTERFACES = ("virtual", "remote", "zenoh", "ipc")
"""python-can interfaces that may carry a simulated robot (besides ``socketcan`` on ``vcan*``)."""


def physical_bus(bus: BusConfig) -> str | None:
    """Why ``bus`` is certainly a real robot's bus (``None``: it may carry a simulator)."""
    if bus.interface == "socketcan":
        if bus.channel.startswith("vcan"):
            return None
        return f"socketcan {bus.channel} is a physical CAN bus (only vcan* can be a simulated bench)"
    if bus.interface in SIMULATION_INTERFACES:
        return None
    return f"interface {bus.interface} is CAN hardware (a simulator runs on virtual, remote, zenoh, ipc or vcan*)"


class LockstepRefused(RequestRefused):
    """Lock-step asked for on a bus that is not a simulated bench."""

    code = "unavailable"


def lockstep_refusal(bus: BusConfig, why: str) -> str:
    """The one line refusing lock-step on ``bus``."""
    return (f"lock-step refused on {bus.describe()}: {why}; lock-step sends the next SYNC when a "
            "simulator has answered, a real robot needs SYNC on the wall clock (--realtime)")


def pacing(requested: str, bus: BusConfig, simulated_bench: bool) -> bool:
    """Real time (``True``) or lock-step for an episode on ``bus``.

    Args:
        requested: one of :data:`PACINGS`.
        simulated_bench: the test-bench node is heard on the bus now.

    Raises:
        LockstepRefused: ``lockstep`` on a bus that is not a simulated bench.
    """
    if requested not in PACINGS:
        raise ValueError(f"pacing {requested!r} not in {PACINGS}")
    real = physical_bus(bus)
    if real is None and not simulated_bench:
        real = "no test-bench node (0x7E) answers: this is not a simulated bench"
    if requested == "lockstep":
        if real is not None:
            raise LockstepRefused(lockstep_refusal(bus, real))
        return False
    return requested == "realtime" or real is not None


class QuickStop(Protocol):
    """What a drive profile does to stop every axis at once (the board profile below; the
    CiA 402 profile commands quick stop through its drive layer)."""

    def stop_commands(self, last: Commands) -> Commands:
        """The commands of the cycle that stops the robot, given the last ones sent."""

    def stop_idle(self, bus) -> None:  # noqa: ANN001 - AgentBus
        """Stop a robot that runs no episode (no SYNC cycle to carry commands)."""


@dataclass(frozen=True)
class BoardQuickStop:
    """uBot boards: control word 0x2011 without ENABLE on every actuated board and zero wheel
    torque; a disabled axis produces zero torque (the boards' safe state, the same as after a
    lost heartbeat), from the SYNC that carries it. The CiA 402 profile's encoder turns the
    same commands into its drives' quick stop (``agent.cia402``)."""

    def stop_commands(self, last: Commands) -> Commands:
        return replace(last, wheel_torque=(0.0, 0.0), control=Control(0), arm_control=Control(0))

    def stop_idle(self, bus) -> None:  # noqa: ANN001 - AgentBus
        """The drive layer's quick stop where it has one (CiA 402: ``Cia402Bus.quick_stop``),
        then NMT pre-operational (broadcast): a board outside OPERATIONAL drives no torque."""
        quick_stop = getattr(bus, "quick_stop", None)
        try:
            if quick_stop is not None:
                quick_stop()
        finally:
            bus.nmt_preop()


class Safety:
    """The e-stop latch and the go latch of one agent (thread-safe: Zenoh callbacks set them,
    the episode thread reads them).

    Attributes:
        pacing: one of :data:`PACINGS` (what the agent was started with).
        estop: set while the e-stop is engaged (the SYNC loop's check, one ``is_set`` a cycle).
    """

    def __init__(self, requested_pacing: str = "auto") -> None:
        if requested_pacing not in PACINGS:
            raise ValueError(f"pacing {requested_pacing!r} not in {PACINGS}")
        self.pacing = requested_pacing
        self.estop = threading.Event()
        self._cond = threading.Condition()
        self._reason = ""
        self._armed = False
        self._waiting = False
        self.engaged_at: float | None = None

    # -- e-stop ------------------------------------------------------------------------------
    def engage(self, reason: str = "") -> None:
        """Latch the e-stop (idempotent; the first reason is kept)."""
        with self._cond:
            if not self.estop.is_set():
                self._reason = reason or "e-stop"
                self.engaged_at = time.monotonic()
                self.estop.set()
            self._armed = False
            self._cond.notify_all()

    def release(self) -> None:
        with self._cond:
            self.estop.clear()
            self._reason, self.engaged_at = "", None
            self._cond.notify_all()

    @property
    def engaged(self) -> str | None:
        """The reason while the e-stop is engaged, else ``None``."""
        with self._cond:
            return self._reason if self.estop.is_set() else None

    def refusal(self) -> str | None:
        """Why no episode may start now (``None``: it may)."""
        reason = self.engaged
        return None if reason is None else (
            f"e-stop engaged ({reason}): release it with 'ersac-hil estop --release'")

    # -- go ----------------------------------------------------------------------------------
    def go(self) -> bool:
        """A person's go: the next episode without a test bench may start. Ignored (``False``)
        while the e-stop is engaged."""
        with self._cond:
            if self.estop.is_set():
                return False
            self._armed = True
            self._cond.notify_all()
            return True

    @property
    def armed(self) -> bool:
        with self._cond:
            return self._armed

    @property
    def waiting(self) -> bool:
        """An episode is waiting for a go right now."""
        with self._cond:
            return self._waiting

    def wait_go(self, timeout_s: float, cancelled: threading.Event | None = None) -> bool:
        """Wait for a go (or take the one already given); ``False`` after ``timeout_s``, on an
        e-stop or when ``cancelled`` is set. A go counts for one episode."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            self._waiting = True
            try:
                while not self._armed:
                    left = deadline - time.monotonic()
                    if left <= 0 or self.estop.is_set() or (cancelled is not None and cancelled.is_set()):
                        return False
                    self._cond.wait(min(left, 0.1))
                if self.estop.is_set():
                    return False
                self._armed = False
                return True
            finally:
                self._waiting = False

    def wake(self) -> None:
        """Let a ``wait_go`` look at its ``cancelled`` event now."""
        with self._cond:
            self._cond.notify_all()


class EstopEngaged(RequestRefused):
    """An episode asked for while the e-stop is engaged."""

    code = "unavailable"
