"""The agent's CANopen master: NMT, SDO configuration, heartbeats, EMCY and the SYNC cycle.

``AgentBus`` owns one ``canopen.Network`` on a ``BusConfig`` with a ``RemoteNode`` per
device (built from the EDS files; PDO maps read from the object dictionary, never uploaded
over SDO). NMT commands and the nodes' NMT states are canopen's NMT master (``network.nmt``,
``node.nmt``); it produces the agent's heartbeat (``HeartbeatProducer``), keeps the age of every
node's heartbeat itself (canopen has no heartbeat consumer), collects EMCY messages, and runs
the cyclic exchange::

    with AgentBus(config) as bus:
        bus.wait_for_nodes()
        bus.nmt_start()
        telemetry = bus.cycle(Commands(wheel_torque=(0.1, 0.1)))   # RPDOs, SYNC, wait TPDOs

``cycle`` sends every RPDO, then SYNC, then waits (up to ``deadline_s``) until every
synchronous TPDO of that SYNC has arrived, and returns the decoded ``Telemetry``. Lock-step
(default): the next SYNC goes out as soon as the caller asks for it, so a simulated robot runs
as fast as it can. Real-time: SYNC is paced by the wall clock at ``period_s``; a cycle that
finishes after its slot counts as an overrun. Failures raise ``PdoTimeout``,
``HeartbeatLost`` or ``BusDown`` (``errors.py``); the caller decides what they end.

Liveness in lock-step: the simulated robot's clock is the SYNC counter, and a loaded machine
may stall the simulator (or this process) for longer than a real robot's deadlines allow: a
stalled simulator is late, not gone, and its plant does not move until it answers. So in
lock-step a node is lost only after ``lockstep_patience_s`` of silence (no TPDO of the cycle,
no heartbeat), and SDO transfers wait as long; a late cycle is waited for and counts nothing.
Real time keeps ``deadline_s`` and ``heartbeat_timeout_s``.

A faulty node on the bus ends the cycle with ``BusFault``, never as data: a TPDO of the wrong
length or twice in one cycle (``tpdos.TpdoCollector``), a frame of a COB-ID that none of the
robot's nodes sends (a foreign SYNC or NMT, a second producer of the agent's RPDOs or
heartbeat, a node babbling on a high-priority id), an error or remote frame, an SDO answer
while no transfer is in flight. ``cycle`` raises the first one recorded since the last check;
``check_bus`` does so between cycles (the end of an episode).

Threads: the bus's receive thread (a python-can Notifier, or CAN over Zenoh's push delivery)
runs the TPDO callbacks (``tpdos.TpdoCollector``) and the heartbeat/EMCY callbacks (short,
under one condition variable); ``cycle``/SDO calls come from one caller thread.
"""
from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from canopen.sdo.constants import REQUEST_ABORTED, RESPONSE_ABORTED

from ersac_hil.agent import configure
from ersac_hil.agent.errors import (BusDown, BusFault, ConfigRefused, HeartbeatLost, NodeMissing,
                                    PdoTimeout, SdoTimeout)
from ersac_hil.agent.policies import ArmImpedance, Spline
from ersac_hil.agent.layout import RobotLayout
from ersac_hil.agent.telemetry import CommandEncoder, Commands, Telemetry, TelemetryDecoder
from ersac_hil.agent.tpdos import TpdoCollector, foreign_frame
from ersac_hil.canbus.heartbeat import HeartbeatProducer
from protocol.can import cobid
from protocol.can.devices import HEARTBEAT_PERIOD_MS, SYNC_PERIOD_S, Device, object_dictionary
from protocol.can.busconfig import BusConfig, open_network, send_frames
from protocol.can.fastpath import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE, BurstNotifier
from protocol.can.lockstep import LOCKSTEP_PATIENCE_S
from protocol.can.objects import Scale
from protocol.can.pdo import PdoSpec, pdo_maps, pdo_struct
from protocol.robot import RobotDescription, default_description

log = logging.getLogger(__name__)

SPIN_S = 0.0003
"""Real time: the last part of the wait for a SYNC's slot spent spinning on the clock, not
asleep (docs/performance.md)."""
SDO_FRAME_BYTES = 8
"""Every SDO request and answer is one frame of 8 bytes (CiA 301)."""


@dataclass(frozen=True)
class BusTiming:
    """Timing of the cyclic exchange.

    Attributes:
        period_s: control period, the SYNC interval in real-time mode (default the robot
            description's, 5 ms: 200 Hz).
        deadline_s: how long a cycle waits for its TPDOs after SYNC (a robot's controllers answer
            within a millisecond; the default leaves room for a simulator on a loaded machine
            and still ends an episode well within a second of the robot going away).
        heartbeat_timeout_s: a node whose last heartbeat is older is lost (producers send
            every 100 ms; the default tolerates five missed heartbeats plus scheduling jitter).
        realtime: pace SYNC by the wall clock instead of lock-step.
        lockstep_patience_s: in lock-step, how long a node may be silent (its TPDOs of a cycle
            missing, its heartbeat stale) before it is lost, and how long an SDO transfer
            waits (a simulator stalled by a loaded machine is late, not gone); at least
            ``deadline_s`` and ``heartbeat_timeout_s``. Unused in real time.
    """
    period_s: float = SYNC_PERIOD_S
    deadline_s: float = 0.25
    heartbeat_timeout_s: float = 0.6
    realtime: bool = False
    lockstep_patience_s: float = LOCKSTEP_PATIENCE_S

    def __post_init__(self) -> None:
        if not (0 < self.period_s <= 1 and 0 < self.deadline_s <= 10 and self.heartbeat_timeout_s > 0
                and self.lockstep_patience_s > 0):
            raise ValueError(f"invalid bus timing {self}")

    @property
    def liveness_s(self) -> float:
        """How old a node's last heartbeat may be for it to count as present."""
        return self.heartbeat_timeout_s if self.realtime else max(self.heartbeat_timeout_s, self.lockstep_patience_s)

    @property
    def tpdo_wait_s(self) -> float:
        """How long a cycle waits for its TPDOs before they count as missing."""
        return self.deadline_s if self.realtime else max(self.deadline_s, self.lockstep_patience_s)


@dataclass(frozen=True)
class EmcyEvent:
    """One EMCY frame: who sent it, code, error register, vendor bytes, and the SYNC cycle
    count when it arrived."""
    device: str
    code: int
    register: int
    data: bytes
    cycle: int
    time_s: float


@dataclass
class CycleTimes:
    """Wall-clock figures of the real-time cycles since ``AgentBus.reset_pacing`` (none in
    lock-step): per cycle, how late its SYNC went out against its slot on the absolute
    schedule (``jitter_s``), and the host's time from the previous cycle's TPDOs to this
    cycle's frames ready to go (``compute_s``: decoding, the controller, the caller's
    observers, encoding the RPDOs; the wait for the slot follows it)."""
    jitter_s: list[float] = field(default_factory=list)
    compute_s: list[float] = field(default_factory=list)


class AgentBus:
    """CANopen master of the uBot (see the module docstring). Not re-entrant: one
    caller thread drives ``cycle`` and the SDO helpers.

    ``description``: the robot (default: the default description); ``devices``: those of its
    nodes this bus talks to (default: all). Where its joints are, which nodes take which
    commands and which a cycle waits for is its ``layout``."""

    def __init__(self, config: BusConfig, devices: tuple[Device, ...] | None = None,
                 timing: BusTiming = BusTiming(), description: RobotDescription | None = None) -> None:
        description = description or default_description()
        devices = description.devices if devices is None else devices
        self.config, self.devices, self.timing = config, tuple(devices), timing
        self.description = description
        self.layout = RobotLayout.of(description, self.devices)
        self.cyclic: tuple[Device, ...] = self.layout.cyclic
        """The devices every SYNC cycle waits for (their heartbeats are checked before each SYNC)."""
        self._by_name = {d.name: d for d in self.devices}
        self._cyclic_names = tuple(d.name for d in self.cyclic)
        self.network: canopen.Network | None = None
        self.nodes: dict[str, canopen.RemoteNode] = {}
        self._heartbeat: HeartbeatProducer | None = None
        self._cond = threading.Condition()
        self._hb_seen: dict[str, float] = {}
        self._emcy: list[EmcyEvent] = []
        self._tpdo_device: dict[int, str] = {}
        self._tpdo_specs: dict[int, PdoSpec] = {}
        self._cyclic_oldest = -math.inf  # the oldest last heartbeat of the cyclic nodes (-inf: one unheard)
        self._decoder: TelemetryDecoder | None = None
        self._tpdos: TpdoCollector | None = None
        self._encoder: CommandEncoder | None = None
        self.cycles = 0
        self.overruns = 0
        self._next_sync: float | None = None
        self._received_at: float | None = None  # when the last real-time cycle had its TPDOs
        self.times = CycleTimes()
        self._last_commands = Commands()
        self._sdo_unanswered: dict[str, int] = {}  # requests sent whose answer has not come, per node
        self._sink: FrameSink | None = None
        #: called on the SYNC loop's thread right after each SYNC is sent, while the nodes
        #: answer it (in lock-step: while the simulator computes): short work that must never
        #: wait but may share the loop's interpreter (the ROS 2 feed's hand-off, ``Feed.pump``)
        self.while_waiting: Callable[[], None] | None = None
        self._tap_listener: _Tap | None = None

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> "AgentBus":
        try:
            self.network = open_network(self.config)
        except (OSError, can.CanError, ValueError) as exc:
            raise BusDown(f"cannot open CAN bus {self.config.describe()}: {exc}") from exc
        net = self.network
        rpdos, sizes = [], {}
        for dev in self.devices:
            node = self._node(dev)
            if not self.timing.realtime:  # a stalled simulator answers late (the module doc)
                node.sdo.RESPONSE_TIMEOUT = max(node.sdo.RESPONSE_TIMEOUT, self.timing.lockstep_patience_s)
            net.add_node(node)
            node.tpdo.read(from_od=True)
            node.rpdo.read(from_od=True)
            self._setup(node)
            node.emcy.add_callback(lambda e, name=dev.name: self._on_emcy(name, e))
            node.nmt.add_heartbeat_callback(lambda state, name=dev.name: self._on_heartbeat(name))
            self.nodes[dev.name] = node
            # cyclic PDOs bypass canopen's per-variable machinery: one struct per frame
            specs = {(p.direction, p.number): p for p in pdo_maps(dev)}
            for number, pdo_map in node.tpdo.map.items():
                if pdo_map.enabled and pdo_map.trans_type and 1 <= pdo_map.trans_type <= 240:
                    spec = specs[("tpdo", number)]
                    net.unsubscribe(pdo_map.cob_id, pdo_map.on_message)
                    sizes[pdo_map.cob_id] = pdo_struct(spec).size
                    self._tpdo_device[pdo_map.cob_id] = dev.name
                    self._tpdo_specs[pdo_map.cob_id] = spec
            if dev in self.layout.actuated:
                rpdos += [(dev.name, m.cob_id, pdo_struct(specs[("rpdo", n)]), specs[("rpdo", n)].keys)
                          for n, m in node.rpdo.map.items() if m.enabled]
        known = _receivable((*self.description.devices, *self.devices))
        self._tpdos, self._encoder = TpdoCollector(sizes, known), self._command_encoder(rpdos)
        if isinstance(net.notifier, BurstNotifier):  # CAN over Zenoh: a SYNC's TPDOs in one call per burst
            net.notifier.intercept(self._tpdos.take)
        else:
            for cob_id in sizes:
                net.subscribe(cob_id, self._tpdos.handler(cob_id))
            net.notifier.add_listener(_ForeignFrames(known, self._tpdos.note))
        for dev in self.devices:  # every SDO answer answers a request (of canopen's client of the node)
            client = self.nodes[dev.name].sdo
            client.send_request, client.read_response = self._counted(dev.name, client)
            net.subscribe(cobid.sdo_tx(dev.node_id), lambda *_, name=dev.name: self._on_sdo_answer(name))
        self._decoder = None  # compiled at the first cycle (a bus of some devices only never cycles)
        self._heartbeat = HeartbeatProducer(net).start()
        return self

    # -- what the drive profile decides (the uBot boards here; ``cia402.Cia402Bus``) ----------
    def _node(self, dev: Device) -> canopen.RemoteNode:
        """The master's node object of ``dev``."""
        return canopen.RemoteNode(dev.node_id, object_dictionary(dev))

    def _setup(self, node: canopen.RemoteNode) -> None:
        """After the node's PDO maps were read from its dictionary, before the cyclic ones are
        taken over by the cycle."""

    def _command_encoder(self, rpdos: list) -> CommandEncoder:
        """``Commands`` -> the RPDO frames of a cycle (``rpdos``: the boards' RPDOs)."""
        return CommandEncoder(rpdos, self.layout)

    def _telemetry_decoder(self) -> TelemetryDecoder:
        """The TPDO frames of a cycle -> ``Telemetry``."""
        return TelemetryDecoder(tuple(self._tpdo_specs.values()), self.layout)

    def apply_impedance(self, impedance: ArmImpedance) -> None:
        """Stiffness and damping of (shoulder, elbow) on both arms, before NMT start."""
        configure.apply_impedance(self, impedance)

    def download_spline(self, side: str, spline: Spline) -> None:
        """Load ``spline`` for the arm ``side``; the commands' START_SPLINE rising edge starts it."""
        configure.download_spline(self, self.layout.arm(side), spline)

    def enable_drives(self) -> None:
        """After NMT start, before the first cycle: the boards enable with the control word in
        their RPDO (nothing to do here)."""

    def disable_drives(self) -> None:
        """At the end of an episode, before NMT pre-operational (the boards drop their torque
        on it: nothing to do here)."""

    def close(self) -> None:
        if self._heartbeat is not None:
            self._heartbeat.stop()
            self._heartbeat = None
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception as exc:  # the bus may already be gone
                log.debug("disconnect: %s", exc)
            self.network = None

    def __enter__(self) -> "AgentBus":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def net(self) -> canopen.Network:
        if self.network is None:
            raise BusDown("the agent's CAN bus is not open")
        return self.network

    def stop_heartbeat(self) -> None:
        """Stop producing the agent's heartbeat (tests of the controllers' safe state)."""
        if self._heartbeat is not None:
            self._heartbeat.stop()

    # -- heartbeats --------------------------------------------------------------------------
    def _on_heartbeat(self, name: str) -> None:
        """canopen's NMT master tracks each node's state; its age is kept here (canopen has
        no heartbeat consumer)."""
        with self._cond:
            seen = self._hb_seen
            seen[name] = time.monotonic()
            if name in self._cyclic_names:
                self._cyclic_oldest = min([seen.get(n, -math.inf) for n in self._cyclic_names])

    def heartbeat_ages(self) -> dict[str, float | None]:
        """Seconds since each device's last heartbeat (``None``: never heard)."""
        now = time.monotonic()
        with self._cond:
            return {d.name: (now - self._hb_seen[d.name]) if d.name in self._hb_seen else None
                    for d in self.devices}

    def nmt_states(self) -> dict[str, str | None]:
        """NMT state each device last reported in its heartbeat."""
        with self._cond:
            heard = set(self._hb_seen)
        states: dict[str, str | None] = {}
        for d in self.devices:
            nmt = self.nodes[d.name].nmt
            with nmt.state_update:  # canopen updates the state under it, after our heartbeat callback
                states[d.name] = nmt.state if d.name in heard else None
        return states

    def present(self, device: Device | str) -> bool:
        """Whether the device's heartbeat is fresh."""
        age = self.heartbeat_ages()[_name(device)]
        return age is not None and age <= self.timing.liveness_s

    def check_heartbeats(self, devices: Iterable[Device | str] | None = None) -> None:
        """Raise ``HeartbeatLost`` for the first device whose heartbeat is stale or missing
        (default: the cyclic devices)."""
        now, timeout = time.monotonic(), self.timing.liveness_s
        if devices is None and now - self._cyclic_oldest <= timeout:
            return  # every cyclic node heard within the timeout (the oldest was)
        names = self._cyclic_names if devices is None else [_name(dev) for dev in devices]
        with self._cond:
            seen = [(name, self._hb_seen.get(name)) for name in names]
        for name, heard in seen:
            if heard is None or now - heard > timeout:
                raise HeartbeatLost(name, None if heard is None else now - heard, timeout)

    def wait_for_nodes(self, devices: Iterable[Device | str] | None = None,
                       timeout_s: float = 2 * HEARTBEAT_PERIOD_MS / 1000 + 0.1) -> None:
        """Block until every device (default: the cyclic ones) has sent a heartbeat;
        ``NodeMissing`` after ``timeout_s``."""
        names = [_name(d) for d in (self.cyclic if devices is None else devices)]
        deadline = time.monotonic() + timeout_s
        while True:
            missing = [n for n in names if not self.present(n)]
            if not missing:
                return
            if time.monotonic() >= deadline:
                raise NodeMissing(tuple(missing), timeout_s)
            time.sleep(0.01)

    # -- EMCY ------------------------------------------------------------------------------
    def _on_emcy(self, name: str, entry) -> None:
        with self._cond:
            self._emcy.append(EmcyEvent(name, int(entry.code), int(entry.register),
                                        bytes(entry.data), self.cycles, time.monotonic()))

    def emcy_events(self, since: int = 0) -> list[EmcyEvent]:
        """EMCY frames received so far (from position ``since`` of the log)."""
        with self._cond:
            return list(self._emcy[since:])

    @property
    def emcy_count(self) -> int:
        with self._cond:
            return len(self._emcy)

    # -- NMT -------------------------------------------------------------------------------
    def nmt_start(self) -> None:
        """NMT start remote node (broadcast): every node to OPERATIONAL."""
        self._nmt("OPERATIONAL")

    def nmt_preop(self) -> None:
        """NMT enter pre-operational (broadcast): cyclic traffic stops."""
        self._nmt("PRE-OPERATIONAL")

    def _nmt(self, state: str) -> None:
        """canopen's NMT master of the network (node-id 0: every node)."""
        try:
            self.net.nmt.state = state
        except (can.CanError, OSError) as exc:
            raise BusDown(f"NMT {state} not sent: {exc}") from exc

    # -- SDO -------------------------------------------------------------------------------
    def _counted(self, name: str, client):  # noqa: ANN001, ANN202
        """``client``'s send and wait, counting what its node owes: a request awaits one
        answer (an abort none); one it gave up waiting for awaits nothing any more, so its late
        answer, like any stray one, is a bus fault and never the answer of a later request."""
        send_request = client.send_request
        asked = [b""]  # the multiplexer (index, sub-index) of the transfer under way

        def send(request) -> None:  # noqa: ANN001
            if request[0] & 0xE0 != REQUEST_ABORTED:
                with self._cond:
                    self._sdo_unanswered[name] = self._sdo_unanswered.get(name, 0) + 1
            if request[0] >> 5 in _SDO_INITIATE:
                asked[0] = bytes(request[1:4])
            send_request(request)

        def wait() -> bytes:
            """canopen's ``read_response`` with the frame checked before it is parsed: an SDO
            frame has 8 bytes, and a shorter one (a faulty node) would crash canopen's client
            in ``struct.unpack_from`` instead of failing the transfer."""
            try:
                response = client.responses.get(block=True, timeout=client.RESPONSE_TIMEOUT)
            except queue.Empty:  # no answer in time: the transfer is over
                with self._cond:
                    self._sdo_unanswered[name] = 0
                raise SdoCommunicationError("No SDO response received") from None
            if len(response) != SDO_FRAME_BYTES:  # not an answer: the transfer is over
                with self._cond:
                    self._sdo_unanswered[name] = 0
                raise BusFault(f"an SDO answer from {name} of {len(response)} bytes (an SDO frame has "
                               f"{SDO_FRAME_BYTES})")
            if response[0] == RESPONSE_ABORTED:
                if bytes(response[1:4]) != asked[0]:  # the abort of another transfer: not ours
                    index, sub = int.from_bytes(response[1:3], "little"), response[3]
                    raise BusFault(f"an SDO abort from {name} for 0x{index:04X}:{sub}, another transfer "
                                   "than the one asked (a second SDO client on the bus?)")
                raise SdoAbortedError(int.from_bytes(response[4:8], "little"))
            return response
        return send, wait

    def _on_sdo_answer(self, name: str) -> None:
        """An answer takes one unanswered request; with none it is a bus fault, and is not
        carried on (a stray answer does not make the node's next answer one too many)."""
        with self._cond:
            unanswered = self._sdo_unanswered.get(name, 0)
            self._sdo_unanswered[name] = max(unanswered - 1, 0)
        if not unanswered:
            self._tpdos.note(f"an SDO answer from {name} to no request")  # type: ignore[union-attr]

    def write(self, device: Device | str, index: int, subindex: int, value: float,
              scale: Scale | None = None) -> int:
        """Download ``value`` (SI with ``scale``, else raw) to ``index:subindex`` of ``device``.

        Returns the raw count written. Raises ``ConfigRefused`` with the abort code when the
        node refuses it (range, read-only...), ``SdoTimeout`` when it does not answer.
        """
        name = _name(device)
        var = _variable(self._by_name[name], index, subindex)
        raw = scale.to_raw(value) if scale is not None else int(value)
        with _sdo_errors(name, index, subindex, value):
            self.nodes[name].sdo.download(index, subindex, var.encode_raw(raw))
        return raw

    def read(self, device: Device | str, index: int, subindex: int = 0,
             scale: Scale | None = None) -> float | int:
        """Upload ``index:subindex`` of ``device`` (SI with ``scale``, else raw)."""
        name = _name(device)
        var = _variable(self._by_name[name], index, subindex)
        with _sdo_errors(name, index, subindex, None):
            raw = var.decode_raw(self.nodes[name].sdo.upload(index, subindex))
        return scale.from_raw(raw) if scale is not None else raw

    # -- the SYNC cycle ---------------------------------------------------------------------
    def reset_pacing(self) -> None:
        """Forget the real-time schedule (the next cycle starts a new one) and its ``times``."""
        self._next_sync = self._received_at = None
        self.times = CycleTimes()

    def _lockstep_heartbeat(self, frames: list[tuple[int, bytes]]) -> None:
        """Lock-step: the agent's heartbeat also goes out before every SYNC that ends a heartbeat
        period (``HEARTBEAT_PERIOD_MS``) of the simulation's clock (the SYNC counter). The controllers' watchdog counts
        the agent's silence in SYNC periods in lock-step; a heartbeat paced by the wall clock
        alone fell behind a fast lock-step on a loaded machine (EMCY 0x8130 in an episode's
        first cycles, ``fault_heartbeat``, while the agent was fine). A stopped producer
        (``stop_heartbeat``) sends none this way either."""
        beat = self._heartbeat
        if beat is not None and beat.running:
            every = max(1, round(HEARTBEAT_PERIOD_MS / 1000 / self.timing.period_s))
            if (self.cycles + 1) % every == 0:
                frames.append(beat.frame())

    def cycle(self, commands: Commands | None = None) -> Telemetry:
        """One SYNC cycle: RPDOs with ``commands`` (the last ones if ``None``), SYNC, then
        every synchronous TPDO of this SYNC, decoded.

        Raises:
            HeartbeatLost: a cyclic node's heartbeat is stale (checked before the SYNC).
            PdoTimeout: some TPDO missing ``deadline_s`` after the SYNC.
            BusDown: the bus failed.
        """
        if commands is not None:
            self._last_commands = commands
        net = self.net
        self.check_heartbeats()
        # encoded before the pacing wait (the cycle count the encoder sees is the last cycle's)
        frames = self._encoder.encode(self._last_commands)  # type: ignore[union-attr]
        realtime = self.timing.realtime
        if not realtime:
            self._lockstep_heartbeat(frames)
        frames.append((cobid.SYNC, b""))
        if realtime:
            if self._received_at is not None:
                self.times.compute_s.append(time.perf_counter() - self._received_at)
            self._pace()
        self.cycles = cycle = self.cycles + 1  # only this thread writes it (EMCY callbacks read it)
        tpdos = self._tpdos
        tpdos.expect()  # type: ignore[union-attr]
        if self._sink is not None and net.burst is not None:  # sent one by one, the tapped send_message has them
            self._sink(time.time(), frames, True)  # queued before they go, so before their answers
        try:
            t0 = time.perf_counter()
            send_frames(net, frames)  # RPDOs then SYNC, one burst where the bus can
        except (can.CanError, OSError, RuntimeError) as exc:
            raise BusDown(f"cycle {cycle}: send failed: {exc}") from exc
        if self.while_waiting is not None:
            self.while_waiting()
        timing = self.timing
        if realtime:
            self.times.jitter_s.append(t0 - self._next_sync)  # type: ignore[operator]
        received, missing = tpdos.wait(t0 + timing.deadline_s, give_up=timing.realtime)  # type: ignore[union-attr]
        silent = ()
        if missing and not timing.realtime:  # lock-step: late, or gone? wait generously
            ages = self.heartbeat_ages()
            silent = [d for d in sorted({self._tpdo_device[c] for c in missing})
                      if ages[d] is None or ages[d] > timing.heartbeat_timeout_s]
            received, missing = tpdos.wait(t0 + timing.tpdo_wait_s)  # type: ignore[union-attr]
        self._received_at = time.perf_counter()
        latency = self._received_at - t0
        if missing:
            self._raise_if_bus_down()
            ages = self.heartbeat_ages()
            silent = [d for d in silent if ages[d] is None or ages[d] > timing.heartbeat_timeout_s]
            if silent:  # its heartbeat had stopped when the TPDO was due, and has not come back
                raise HeartbeatLost(silent[0], ages[silent[0]], timing.heartbeat_timeout_s)
            names = tuple(sorted(f"{self._tpdo_device[c]}:0x{c:03X}" for c in missing))
            raise PdoTimeout(cycle, names, timing.tpdo_wait_s)
        self.check_bus(cycle)
        if self.timing.realtime and time.perf_counter() > self._next_sync + self.timing.period_s:
            self.overruns += 1
        if self._decoder is None:
            self._decoder = self._telemetry_decoder()
        return self._decoder.decode(cycle, received, latency)

    def check_bus(self, cycle: int | None = None) -> None:
        """Raise ``BusFault`` for the first fault of a node on the bus recorded since the last
        check (see the module doc)."""
        fault = self._tpdos.fault() if self._tpdos is not None else None
        if fault is not None:
            raise BusFault(f"SYNC cycle {self.cycles if cycle is None else cycle}: {fault}")

    def _pace(self) -> None:
        """Until the next slot of the absolute schedule (``period_s`` apart from the first):
        asleep until ``SPIN_S`` before it, then spinning on the clock (a sleeping thread wakes
        tens to hundreds of microseconds late on a virtual machine)."""
        now = time.perf_counter()
        period = self.timing.period_s
        if self._next_sync is None:
            self._next_sync = now
        else:
            self._next_sync += period
            if self._next_sync < now - period:  # more than a slot behind: re-phase
                self.overruns += 1
                self._next_sync = now
        due = self._next_sync
        wait = due - SPIN_S - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        while time.perf_counter() < due:
            pass

    # -- a recorder's tap on the agent's own bus (``ersac_hil.ros2``: MCAP episodes) ------------
    def tap(self, sink: FrameSink | None) -> None:
        """From now on also hand ``sink(timestamp, frames, sent)`` every frame of this bus: each
        frame the agent sends (``sent=True``; ``(COB-ID, data)`` pairs, ``(id, flags, dlc,
        data)`` for a remote or extended one), stamped just before it goes - each SYNC cycle's
        RPDOs, SYNC and lock-step heartbeat as one burst, and one by one the NMT commands, SDO
        requests and timer heartbeats (everything ``Network.send_message`` sends) - and every
        frame received (``protocol.can.fastpath.Frame`` tuples), on the sending or receiving
        thread, so it must only queue them. A frame's answer reaches the sink after it. No
        second bus is opened; ``None`` removes it."""
        net = self.net
        notifier = net.notifier
        self._sink = sink
        net.__dict__.pop("send_message", None)
        if sink is not None:
            net.send_message = self._tapped_send(type(net).send_message.__get__(net), sink)
        if isinstance(notifier, BurstNotifier):
            notifier.intercept(self._tpdos.take if sink is None else self._take_tapped)  # type: ignore[union-attr]
            return
        if self._tap_listener is not None:
            notifier.remove_listener(self._tap_listener)
            self._tap_listener = None
        if sink is not None:
            self._tap_listener = _Tap(sink)
            notifier.add_listener(self._tap_listener)

    @staticmethod
    def _tapped_send(send, sink: FrameSink):  # noqa: ANN001, ANN205 - Network.send_message and its wrapper
        def tapped(can_id: int, data, remote: bool = False) -> None:  # noqa: ANN001 - bytes-like or list
            data = bytes(data)
            if remote or can_id > 0x7FF:
                flags = (FLAG_REMOTE if remote else 0) | (FLAG_EXTENDED if can_id > 0x7FF else 0)
                sink(time.time(), [(can_id, flags, len(data), data)], True)
            else:
                sink(time.time(), [(can_id, data)], True)
            send(can_id, data, remote)
        return tapped

    def _take_tapped(self, frames: list, timestamp: float) -> list:
        self._sink(timestamp, frames, False)  # type: ignore[misc]
        return self._tpdos.take(frames, timestamp)  # type: ignore[union-attr]

    def _raise_if_bus_down(self) -> None:
        try:
            self.net.check()
        except Exception as exc:
            raise BusDown(f"CAN receive thread stopped: {exc}") from exc


_SDO_INITIATE = (1, 2, 5, 6)
"""Client command specifiers that name a transfer's multiplexer (CiA 301: initiate download,
initiate upload, block download, block upload); a server's abort carries the same one."""


def _receivable(devices: Iterable[Device]) -> frozenset[int]:
    """The COB-IDs the robot's nodes send (``devices``: every node of the robot, not only those
    the bus talks to): TPDOs, EMCY, SDO answers, heartbeats. Any other frame the agent hears is
    foreign."""
    ids: set[int] = set()
    for dev in set(devices):
        ids |= {cobid.emcy(dev.node_id), cobid.sdo_tx(dev.node_id), cobid.heartbeat(dev.node_id)}
        ids |= {p.cob_id for p in pdo_maps(dev) if p.direction == "tpdo"}
    return frozenset(ids)


class _ForeignFrames(can.Listener):
    """Every frame the agent hears, beside canopen's dispatch (which drops error and remote
    frames unseen): records foreign ones (``known``: what the robot's nodes send)."""

    def __init__(self, known: frozenset[int], note) -> None:  # noqa: ANN001
        self._known, self._note = known, note

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.arbitration_id not in self._known:
            self._note(foreign_frame(msg.arbitration_id, msg.is_error_frame, msg.is_remote_frame))


FrameSink = Callable[[float, list, bool], None]
"""``(timestamp, frames, sent)``: see :meth:`AgentBus.tap`."""


class _Tap(can.Listener):
    """Every received frame to a :data:`FrameSink` (the frame-by-frame receive path)."""

    def __init__(self, sink: FrameSink) -> None:
        self._sink = sink

    def on_message_received(self, msg: can.Message) -> None:
        flags = ((FLAG_EXTENDED if msg.is_extended_id else 0) | (FLAG_REMOTE if msg.is_remote_frame else 0)
                 | (FLAG_ERROR if msg.is_error_frame else 0))
        self._sink(msg.timestamp, [(msg.arbitration_id, flags, msg.dlc, msg.data)], False)


@contextmanager
def _sdo_errors(name: str, index: int, subindex: int, value: float | None) -> Iterator[None]:
    """An SDO transfer's failures as the agent's errors: the node's abort (``ConfigRefused``
    with its code), no answer (``SdoTimeout``), a bus that cannot send (``BusDown``)."""
    try:
        yield
    except SdoAbortedError as exc:
        raise ConfigRefused(name, index, subindex, value, exc.code) from exc
    except SdoCommunicationError as exc:
        raise SdoTimeout(f"{name} 0x{index:04X}:{subindex}: {exc}") from exc
    except (can.CanError, OSError) as exc:
        raise BusDown(f"SDO to {name} not sent: {exc}") from exc


def _name(device: Device | str) -> str:
    return device if isinstance(device, str) else device.name


def _variable(dev: Device, index: int, subindex: int) -> ODVariable:
    entry = object_dictionary(dev)[index]
    return entry if isinstance(entry, ODVariable) else entry[subindex]
