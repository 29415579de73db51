"""The simulated robot on the bus: one simulator, its CANopen nodes (the boards, or one CiA 402
drive per axis: ``firmware_sim.nodes.cia402``; the IMU and the test bench), SYNC-driven stepping.

Lock-step (default): each SYNC applies the RPDOs received since the previous SYNC, advances
exactly one control period of physics, sends the failure EMCYs of that period, then every
node samples and sends its synchronous TPDOs. Real-time: SYNC applies commands, samples and
answers from the present state at once (as a drive samples at SYNC; a CiA 402 drive whose
SYNC commands are only targets takes them right after its answer), and a physics thread
advances one period right after each answer (and then runs the nodes' watchdog ticks:
heartbeats, the agent's heartbeat watched); it steps on the wall clock (overruns counted)
whenever no SYNC has come for half a period past its due time (the agent between episodes),
except from a scenario's start (``reset``) to the first SYNC after it: the test bench holds the
robot in the scenario's initial state until the episode begins, as lock-step does (no plant time
passes without a SYNC). Without the hold the plant ran on, its axes without torque, for as long
as the agent took from the reset to its first SYNC: a few milliseconds on the boards, which
enable with their first RPDO, but the whole power-up of seven CiA 402 drives (their state
machines walked one by one over SDO: 0.1-0.5 s, 1 s on a loaded machine), in which the
lifting arms sagged under the bottle and its grasp broke before the episode began.
So a SYNC never waits for a physics step: on two cores under ``SCHED_FIFO`` a step running
when a SYNC arrives held the receive thread off its processor and the GIL for as long as
the step took (the bulk of the real-time tail, docs/performance.md). In lock-step the
controllers' watchdog on the agent's heartbeat counts SYNC periods as well as the wall clock
(``SlaveNode``'s ``lockstep_period_s``): an agent a loaded machine stalls is not lost.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass


from firmware_sim.nodes.base import WATCHDOG_TICK_S, NodeApplication, SlaveNode
from firmware_sim.nodes.cia402 import DriveApp, DriveCounts, drive_scaling
from firmware_sim.nodes.devices import APPS, AxisCounts, telemetry_row
from firmware_sim.nodes.sampler import TpdoSampler
from firmware_sim.controllers import BOARDS
from firmware_sim.plant.overrides import PhysicsOverrides
from firmware_sim.simulator import FailureKind, Simulator
from protocol.can import cia402, cobid
from protocol.can.devices import DEVICES, SYNC_PERIOD_S, Device
from protocol.can.busconfig import BusConfig, open_network, send_frames
from protocol.can.objects import EmcyCode, Index
from protocol.robot import RobotDescription

log = logging.getLogger(__name__)

_STATE_COMMANDS = frozenset({(cia402.Index.CONTROLWORD, 0), (cia402.Index.MODES_OF_OPERATION, 0)})
"""A drive's objects that change its statusword (and so the TPDOs of the SYNC they come with)."""

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
    held: int = 0
    """Real time: the physics thread's clock steps not taken, the scenario's start held."""


def realtime_schedule(synced: bool, now: float, last: float, next_t: float, period: float) -> tuple[bool, float]:
    """The real-time physics thread's decision at ``now`` (``last``: its last step, ``next_t``:
    its next step on the clock): whether to step, and when to step on the clock next.
    ``synced``: woken by a SYNC's answer: a step (unless the clock stepped less than half a
    period before: that period is done), the clock only 1.5 periods on (a SYNC due a period on
    comes first, so a step never runs when it arrives); else the clock's step, one period on."""
    if synced:
        return now - last >= period / 2, now + 1.5 * period
    return True, next_t + period


class SimulatedRobot:
    """Start with ``SimulatedRobot(bus_config)``; ``close()`` takes every node off the bus."""

    def __init__(self, bus_config: BusConfig, *, seed: int = 0, realtime: bool = False,
                 control_period: float | None = None, substeps: int = 5,
                 devices: tuple[Device, ...] = DEVICES, physics: PhysicsOverrides = PhysicsOverrides(),
                 encoder_counts: Mapping[str, int] | None = None,
                 description: RobotDescription | None = None) -> None:
        """``devices``: the nodes (a CiA 402 node per axis where their profile is ``cia402``);
        ``encoder_counts``: increments per motor revolution of those drives by joint (default
        ``cia402.ENCODER_INCREMENTS``); ``description``: both from a robot description;
        ``control_period``: physics per SYNC (default the description's SYNC period, 5 ms)."""
        if description is not None:
            devices = description.devices
            encoder_counts = {a.name: a.encoder_counts for a in description.axes if a.encoder_counts}
        if control_period is None:
            control_period = SYNC_PERIOD_S if description is None else description.bus.sync_period_s
        self.devices = devices
        self.realtime = realtime
        self.lock = threading.RLock()
        self.stats = RobotStats()
        self.sim = Simulator(control_period, substeps, physics=physics)
        self.sim.reset("idle", seed)
        drives = [d for d in devices if getattr(d, "profile", "ubot-board") == "cia402"]
        counts = encoder_counts or {}
        scalings = {d.joints[0]: drive_scaling(self, d.joints[0], counts.get(d.joints[0], cia402.ENCODER_INCREMENTS))
                    for d in drives}
        self._drives = DriveCounts(scalings) if drives else None
        self._node_of_joint = {j: d.name for d in devices for j in d.joints}
        self.network = open_network(bus_config)
        self.nodes: dict[str, SlaveNode] = {}
        for d in devices:
            app = (DriveApp(self, d, scalings[d.joints[0]], self._drives) if d in drives
                   else APPS[d.name](self, d))
            self.nodes[d.name] = SlaveNode(d, app, own_sync=False, watchdog=not realtime,
                                           lockstep_period_s=None if realtime else control_period)
        for node in self.nodes.values():
            node.connect(self.network)
        # real time: drives whose SYNC commands are only targets take them after the answer
        # (a drive samples at SYNC; the targets change none of this SYNC's TPDOs, and the physics
        # step that uses them follows the answer either way)
        self.targets_after_answer = tuple(n for n in self.nodes.values() if realtime and isinstance(n.app, DriveApp)
                                   and not n.synchronous_rpdo_keys & _STATE_COMMANDS)
        self._on_sync_apps = [n.app for n in self.nodes.values()
                              if type(n.app).on_sync is not NodeApplication.on_sync]
        self._sampler = TpdoSampler(tuple(self.nodes.values()))
        self.network.subscribe(cobid.SYNC, self._on_sync)
        self._stop = threading.Event()
        self._answered = threading.Event()  # real time: a SYNC was answered, step now
        self._sampled: tuple[list[int], list[int]] | None = None  # real time: counts after the last step
        self._held = False  # real time: from a scenario reset to the first SYNC after it, not stepped
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
                    node.app.on_failure(_EMCY_OF[ev.kind])
                    node.emergency(_EMCY_OF[ev.kind])

    def _emcy_sources(self, ev) -> tuple[str, ...]:
        boards = ("arm_left", "arm_right")  # bottle dropped: both hands lose their load
        if ev.board:
            boards = (ev.board,)
        elif ev.kind == FailureKind.FALLEN:
            return ("imu",)
        if self._drives is None:
            return boards
        if ev.kind == FailureKind.OVER_CURRENT:  # one drive per axis: the axis's own
            return (self._node_of_joint[ev.axis],)
        # the arm goes limp (cable) / lets go (bottle): every drive of the arm
        return tuple(self._node_of_joint[j] for b in boards for j in BOARDS[b] if j in self._node_of_joint)

    def _on_sync(self, can_id, data, timestamp) -> None:
        after = self.targets_after_answer
        with self.lock:
            self._held = False
            for node in self.nodes.values():
                if node not in after:
                    node.apply_commands()
                node.agent_sync()
            for app in self._on_sync_apps:
                app.on_sync()
            if not self.realtime:
                self._step()
            frames: list[tuple[int, bytes]] = []
            sampled = self._sampled
            if sampled is None:
                axes = AxisCounts.sample(self.sim)  # once for every node's TPDOs
                row = self._row(axes)
            else:  # real time: the counts of the state the last step left, taken right after it
                axes = AxisCounts.sample(self.sim, sampled[0])
                row = list(sampled[1])  # the sampler writes each node's status word into it
            self._sampler.pack(row, axes, frames)
            send_frames(self.network, frames)
            for node in after:
                node.apply_commands()
        if self.realtime:
            self._answered.set()

    def _row(self, axes: AxisCounts) -> list[int]:
        row = telemetry_row(axes, self.sim.imu())
        if self._drives is not None:  # the drives' counts after the boards'
            row += self._drives.row(self.sim.axis_values())
        return row

    def axis_counts(self) -> AxisCounts:
        """The raw axis telemetry of the present state."""
        return AxisCounts.sample(self.sim)

    def telemetry(self) -> list[int]:
        """The robot's telemetry row of the present state (``devices.telemetry_row``, then
        the CiA 402 drives' counts: ``cia402.DriveCounts``)."""
        return self._row(AxisCounts.sample(self.sim))

    def _run_realtime(self) -> None:
        """The physics thread (see the module doc and ``realtime_schedule``); after each step
        the telemetry counts of the new state, for the next SYNC's answer, and every
        ``WATCHDOG_TICK_S`` the nodes' watchdog ticks (heartbeats, event TPDOs, the agent's
        heartbeat watched): in the quiet part of the period, where one thread per node waking on
        its own timer would also wake when a SYNC is due and contend for the interpreter with
        its answer."""
        period, clock, answered = self.sim.control_period, time.monotonic, self._answered
        nodes = tuple(self.nodes.values())
        last = next_t = next_tick = clock()
        while True:
            synced = answered.wait(max(0.0, next_t - clock()))
            if self._stop.is_set():
                return
            if synced:
                answered.clear()
            now = clock()
            step, next_t = realtime_schedule(synced, now, last, next_t, period)
            if step:
                with self.lock:
                    if self._held:  # the test bench holds the scenario's start (module doc)
                        self.stats.held += 1
                    else:
                        self._step()
                        try:
                            axes = AxisCounts.sample(self.sim)
                            self._sampled = (axes.values, self._row(axes))
                        except ValueError:  # a NaN: the SYNC samples (and fails) as in lock-step
                            self._sampled = None
                        last = now
            if not synced and next_t < clock():
                self.stats.overruns += 1
                next_t = clock()
            now = clock()
            if now >= next_tick:
                next_tick = now + WATCHDOG_TICK_S
                for node in nodes:
                    try:
                        node.tick(now)
                    except Exception:  # noqa: BLE001 - as the node's own thread would end: the physics goes on
                        log.exception("node %#x: watchdog tick failed", node.id)

    # -- test bench --------------------------------------------------------------------------
    def reset(self, scenario: str, seed: int) -> None:
        """New episode: physics to the scenario's initial state, boards to power-on defaults."""
        with self.lock:
            self.sim.reset(scenario, seed)
            self._sampled = None
            self._held = self.realtime
            self.stats.resets += 1
            for node in self.nodes.values():
                for index in _CONFIG_INDEXES:
                    node.data_store.pop(index, None)
                node.reset_application()

    def close(self) -> None:
        self._stop.set()
        self._answered.set()
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
