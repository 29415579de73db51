"""The simulated robot on the bus: one simulator, six CANopen nodes, SYNC-driven stepping.

Lock-step (default): each SYNC applies the RPDOs received since the previous SYNC, advances
exactly one control period of physics, sends the failure EMCYs of that period, then every
node samples and sends its synchronous TPDOs. Real-time: a physics thread steps on the wall
clock (overruns counted) and SYNC only applies commands and samples. In lock-step the
controllers' watchdog on the agent's heartbeat counts SYNC periods as well as the wall clock
(``SlaveNode``'s ``lockstep_period_s``): an agent a loaded machine stalls is not lost.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass


from firmware_sim.nodes.base import SlaveNode
from firmware_sim.nodes.devices import APPS, AxisCounts, telemetry_row
from firmware_sim.nodes.sampler import TpdoSampler
from firmware_sim.plant.overrides import PhysicsOverrides
from firmware_sim.simulator import FailureKind, Simulator
from protocol.can import cobid
from protocol.can.devices import DEVICES, Device
from protocol.can.busconfig import BusConfig, open_network, send_frames
from protocol.can.objects import EmcyCode, Index

log = logging.getLogger(__name__)

_EMCY_OF = {FailureKind.OVER_CURRENT: EmcyCode.OVER_CURRENT, FailureKind.CABLE_BROKEN: EmcyCode.CABLE_BROKEN,
            FailureKind.FALLEN: EmcyCode.FALLEN, FailureKind.BOTTLE_DROPPED: EmcyCode.BOTTLE_DROPPED}

# config objects that return to their EDS defaults when the test bench resets the scenario
_CONFIG_INDEXES = {Index.POSITION_LIMIT_MIN, Index.POSITION_LIMIT_MAX, Index.VELOCITY_LIMIT,
                   Index.SPLINE_KNOT_COUNT, Index.SPLINE_KNOT_TIME} | {
    i for i in range(Index.SPLINE_POSITION, Index.SPLINE_POSITION + 4)}


@dataclass
class RobotStats:
    cycles: int = 0
    step_seconds: float = 0.0
    overruns: int = 0
    resets: int = 0


class SimulatedRobot:
    """Start with ``SimulatedRobot(bus_config)``; ``close()`` takes every node off the bus."""

    def __init__(self, bus_config: BusConfig, *, seed: int = 0, realtime: bool = False,
                 control_period: float = 0.005, substeps: int = 5,
                 devices: tuple[Device, ...] = DEVICES, physics: PhysicsOverrides = PhysicsOverrides()) -> None:
        self.devices = devices
        self.realtime = realtime
        self.lock = threading.RLock()
        self.stats = RobotStats()
        self.sim = Simulator(control_period, substeps, physics=physics)
        self.sim.reset("idle", seed)
        self.network = open_network(bus_config)
        self.nodes: dict[str, SlaveNode] = {}
        for d in devices:
            self.nodes[d.name] = SlaveNode(d, APPS[d.name](self, d), own_sync=False,
                                           lockstep_period_s=None if realtime else control_period)
        for node in self.nodes.values():
            node.connect(self.network)
        self._sampler = TpdoSampler(tuple(self.nodes.values()))
        self.network.subscribe(cobid.SYNC, self._on_sync)
        self._stop = threading.Event()
        self._physics: threading.Thread | None = None
        if realtime:
            self._physics = threading.Thread(target=self._run_realtime, name="physics", daemon=True)
            self._physics.start()

    # -- stepping ------------------------------------------------------------------------
    def _step(self) -> None:
        t0 = time.perf_counter()
        events = self.sim.step()
        self.stats.step_seconds += time.perf_counter() - t0
        self.stats.cycles += 1
        for ev in events:
            for name in self._emcy_sources(ev):
                node = self.nodes.get(name)
                if node is not None and node.operational:
                    node.emergency(_EMCY_OF[ev.kind])

    @staticmethod
    def _emcy_sources(ev) -> tuple[str, ...]:
        if ev.board:
            return (ev.board,)
        if ev.kind == FailureKind.FALLEN:
            return ("imu",)
        return ("arm_left", "arm_right")  # bottle dropped: both hands lose their load

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self.lock:
            for node in self.nodes.values():
                node.apply_commands()
                node.agent_sync()
            if not self.realtime:
                self._step()
            frames: list[tuple[int, bytes]] = []
            axes = AxisCounts.sample(self.sim)  # once for every node's TPDOs
            self._sampler.pack(telemetry_row(axes, self.sim.imu()), axes, frames)
            send_frames(self.network, frames)

    def axis_counts(self) -> AxisCounts:
        """The raw axis telemetry of the present state."""
        return AxisCounts.sample(self.sim)

    def telemetry(self) -> list[int]:
        """The robot's telemetry row of the present state (``devices.telemetry_row``)."""
        return telemetry_row(AxisCounts.sample(self.sim), self.sim.imu())

    def _run_realtime(self) -> None:
        period = self.sim.control_period
        next_t = time.monotonic()
        while not self._stop.is_set():
            with self.lock:
                self._step()
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:
                self.stats.overruns += 1
                next_t = time.monotonic()
            elif self._stop.wait(delay):
                break

    # -- test bench --------------------------------------------------------------------------
    def reset(self, scenario: str, seed: int) -> None:
        """New episode: physics to the scenario's initial state, boards to power-on defaults."""
        with self.lock:
            self.sim.reset(scenario, seed)
            self.stats.resets += 1
            for node in self.nodes.values():
                for index in _CONFIG_INDEXES:
                    node.data_store.pop(index, None)
                node.reset_application()

    def close(self) -> None:
        self._stop.set()
        if self._physics is not None:
            self._physics.join(timeout=1.0)
        self.network.unsubscribe(cobid.SYNC, self._on_sync)
        for node in self.nodes.values():
            node.close()
        self.network.disconnect()

    def __enter__(self) -> "SimulatedRobot":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
