"""The firmware's CANopen stack: a CiA 301 slave built from a device's EDS file.

``SlaveNode`` extends canopen's ``LocalNode`` with what canopen 2.4 leaves to the application
(its LocalNode ignores SYNC, keeps RPDO values out of the object dictionary, has no heartbeat
consumer and sends no boot-up after an NMT reset): EDS value-range checks on SDO download (abort 0x0609003x), RPDO values kept
as application state and applied at the next SYNC, TPDOs sampled from that state and sent
after each SYNC, a heartbeat producer on our own timer (python-can-remote's periodic tasks
cannot change data), boot-up after an NMT reset, and a consumer-heartbeat watchdog on the
agent (0x1016) that puts the node in its safe state with EMCY 0x8130 (in lock-step the
agent's silence also counts in SYNC periods: ``lockstep_period_s``).

What a device *does* lives in a ``NodeApplication`` (the simulator's controllers; or
``StaticApplication``, the minimal reference behaviour the conformance suite also runs on).
All callbacks run on the python-can Notifier thread or the node's watchdog thread: keep
applications short and thread-safe.
"""
from __future__ import annotations

import logging
import operator
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import canopen
from canopen.nmt import NMT_COMMANDS, NmtSlave
from canopen.sdo import SdoAbortedError

from protocol.can import cobid
from protocol.can.devices import AGENT_NODE_ID, Device, object_dictionary
from protocol.can.lockstep import LOCKSTEP_PATIENCE_S
from protocol.can.nmt import INITIALISING, OPERATIONAL, PRE_OPERATIONAL
from protocol.can.objects import EMCY_REGISTER, EmcyCode, Index, Status
from protocol.can.pdo import pdo_maps, pdo_struct
from protocol.can.sdo import check_range

from firmware_sim.nodes.inbox import RpdoInbox

log = logging.getLogger(__name__)

Key = tuple[int, int]
WATCHDOG_TICK_S = 0.02
"""Heartbeat production and consumer check resolution (loss detected within 20 ms)."""


def tuple_getter(keys: tuple) -> Callable[[Any], tuple[int, ...]]:
    """The values at ``keys`` of a dict (object keys) or a list (slots) as a tuple
    (``operator.itemgetter``, always a tuple)."""
    get = operator.itemgetter(*keys)
    return get if len(keys) > 1 else (lambda values: (get(values),))


@dataclass(frozen=True)
class TpdoLayout:
    """One synchronous TPDO of a node: its COB-ID, sent every ``every``-th SYNC (the
    transmission type 1..240), packed by ``layout`` from the objects ``keys`` (in frame order);
    ``values_of`` picks those objects' values from a dict keyed like ``keys``."""

    cob_id: int
    every: int
    layout: struct.Struct
    keys: tuple[Key, ...]
    values_of: Callable[[dict[Key, int]], tuple[int, ...]]

    def due(self, sync_count: int) -> bool:
        """Sent at the node's ``sync_count``-th SYNC (counted from 1; 0: the node sends none)."""
        return sync_count > 0 and sync_count % self.every == 0


@dataclass(frozen=True)
class EventTpdo:
    """One event-driven TPDO of a node (transmission type 254/255): sent when its data changes
    (``SlaveNode.send_event_tpdos``) and at least every ``timer_s`` (0: no timer)."""

    cob_id: int
    layout: struct.Struct
    keys: tuple[Key, ...]
    timer_s: float


EVENT_DRIVEN = (254, 255)
"""Transmission types of event-driven PDOs: an RPDO applied on arrival, a TPDO sent on change."""


class NodeApplication:
    """Hooks a device implements. The defaults are the reference (static) behaviour."""

    def attach(self, node: "SlaveNode") -> None:
        self.node = node

    def on_commands(self, changed: dict[Key, int]) -> None:
        """RPDO values that changed, applied at SYNC (raw integers)."""

    def read(self, key: Key) -> int | None:
        """Live value for an SDO upload (ground truth, counters); ``None``: use stored data."""
        return None

    def on_config(self, key: Key, value: int | float | str) -> None:
        """An SDO download passed the range check; raise ``SdoAbortedError`` to refuse it."""

    def sample(self) -> None:
        """Refresh telemetry values (``node.set_value``) before the TPDOs go out."""

    def on_nmt_state(self, state: str) -> None:
        """NMT state changed (``"OPERATIONAL"``, ``"STOPPED"``, ...)."""

    def on_heartbeat_lost(self) -> None:
        """The agent's heartbeat stopped: go to the safe state (zero torque)."""

    def on_reset(self) -> None:
        """NMT reset node: back to power-on defaults."""

    def on_sync(self) -> None:
        """At every SYNC on a simulated robot, after the commands applied and before the
        physics step (only applications that override it are called)."""

    def on_failure(self, code: EmcyCode) -> None:
        """A plant failure of this device, just before its EMCY ``code`` goes out."""


class StaticApplication(NodeApplication):
    """Reference behaviour: commands are stored, telemetry stays at its defaults, the status
    word (0x2010) reports OPERATION_ENABLED and SAFE_STATE."""

    def _status(self, set_bits: Status = Status(0), clear_bits: Status = Status(0)) -> None:
        status = Status(int(self.node.value(Index.STATUS, 0)))
        self.node.set_value(Index.STATUS, 0, int((status | set_bits) & ~clear_bits))

    def on_nmt_state(self, state: str) -> None:
        if state == "OPERATIONAL":
            self._status(Status.OPERATION_ENABLED, Status.SAFE_STATE)
        else:
            self._status(clear_bits=Status.OPERATION_ENABLED)

    def on_heartbeat_lost(self) -> None:
        self._status(Status.SAFE_STATE | Status.FAULT, Status.OPERATION_ENABLED)


class _Nmt(NmtSlave):
    """NMT slave whose heartbeat is produced by ``SlaveNode``'s own timer."""

    def __init__(self, node: "SlaveNode") -> None:
        super().__init__(node.id, node)
        self._node = node

    def start_heartbeat(self, heartbeat_time_ms: int) -> None:  # own timer instead
        self._heartbeat_time_ms = heartbeat_time_ms

    def stop_heartbeat(self) -> None:
        pass

    def update_heartbeat(self) -> None:
        pass

    def on_command(self, can_id, data, timestamp):
        old = self._state
        cmd, target = struct.unpack_from("BB", data)
        super().on_command(can_id, data, timestamp)
        if target in (self.id, 0) and cmd in (NMT_COMMANDS["RESET"], NMT_COMMANDS["RESET COMMUNICATION"]):
            self._node._after_reset(full=cmd == NMT_COMMANDS["RESET"])
        elif self._state != old:
            self._node._state_changed()


class SlaveNode(canopen.LocalNode):
    """One device on the bus. ``connect(network)`` brings it up (boot-up message,
    PRE-OPERATIONAL, heartbeat); ``close()`` takes it off again.

    With ``own_sync=True`` the node reacts to SYNC itself (apply commands, sample, send);
    a simulator that steps physics between those two calls passes ``False`` and calls
    ``apply_commands()`` and ``due_tpdos()`` from its own SYNC handler (packing the due
    TPDOs of all its nodes from one sample).

    Its heartbeat, event-driven TPDOs and watch on the agent's heartbeat run on a thread of its
    own every ``WATCHDOG_TICK_S``; with ``watchdog=False`` the owner calls :meth:`tick` as
    often instead (a real-time simulator from its physics thread, so no thread per node wakes
    when a SYNC is due).
    """

    def __init__(self, device: Device, app: NodeApplication | None = None, *, own_sync: bool = True,
                 lockstep_period_s: float | None = None, watchdog: bool = True) -> None:
        super().__init__(device.node_id, object_dictionary(device))
        self.device = device
        self.app = app or StaticApplication()
        self.own_sync = own_sync
        self.nmt = _Nmt(self)
        self._write_callbacks = [self._on_sdo_write]
        self.add_read_callback(self._on_sdo_read)
        self._lock = threading.RLock()
        self._values: dict[Key, int] = {}
        self._inbox = RpdoInbox(())
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        self._own_watchdog = watchdog
        self._next_hb = 0.0
        self._agent_last_hb: float | None = None
        self._hb_lost = False
        self._lockstep_period_s = lockstep_period_s
        self._syncs_since_hb = 0
        self.sync_count = 0
        self._layouts: list[TpdoLayout] = []
        self._events: list[EventTpdo] = []
        self._event_sent: dict[int, tuple[bytes, float]] = {}
        self._rpdo_handlers: list[tuple[int, object]] = []
        self.app.attach(self)

    # -- lifecycle -------------------------------------------------------------------------
    def connect(self, network: canopen.Network) -> None:
        network.add_node(self)
        self.tpdo.read(from_od=True)
        self.rpdo.read(from_od=True)
        specs = {(p.direction, p.number): p for p in pdo_maps(self.device)}
        # cyclic PDOs bypass canopen's per-variable machinery: frames kept whole until SYNC;
        # event-driven RPDOs take effect on arrival
        rpdos = [(pdo_map, specs[("rpdo", number)]) for number, pdo_map in self.rpdo.map.items()
                 if pdo_map.enabled and pdo_map.cob_id]
        synchronous = [(m, spec) for m, spec in rpdos if m.trans_type not in EVENT_DRIVEN]
        self._inbox = RpdoInbox([spec for _, spec in synchronous])
        handlers = [(m.cob_id, self._rpdo_handler(slot)) for slot, (m, _) in enumerate(synchronous)]
        handlers += [(m.cob_id, self._event_rpdo_handler(spec)) for m, spec in rpdos
                     if m.trans_type in EVENT_DRIVEN]
        for pdo_map, _ in rpdos:
            network.unsubscribe(pdo_map.cob_id, pdo_map.on_message)
        for cob_id, handler in handlers:
            network.subscribe(cob_id, handler)
            self._rpdo_handlers.append((cob_id, handler))
        self._layouts = [TpdoLayout(m.cob_id, m.trans_type, pdo_struct(spec), spec.keys, tuple_getter(spec.keys))
                         for n, m in self.tpdo.map.items() for spec in (specs[("tpdo", n)],)
                         if m.enabled and 1 <= (m.trans_type or 0) <= 240]
        self._events = [EventTpdo(m.cob_id, pdo_struct(spec), spec.keys, (m.event_timer or 0) / 1000.0)
                        for n, m in self.tpdo.map.items() for spec in (specs[("tpdo", n)],)
                        if m.enabled and m.trans_type in EVENT_DRIVEN]
        network.subscribe(cobid.heartbeat(AGENT_NODE_ID), self._on_agent_heartbeat)
        if self.own_sync:
            network.subscribe(cobid.SYNC, self._on_sync)
        self._boot()
        self._stop.clear()
        self._next_hb = time.monotonic()
        if self._own_watchdog:
            self._watchdog = threading.Thread(target=self._watch, name=f"node-{self.id:#x}", daemon=True)
            self._watchdog.start()

    def close(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=1.0)
            self._watchdog = None
        if self.has_network():
            net = self.network
            net.unsubscribe(cobid.heartbeat(AGENT_NODE_ID), self._on_agent_heartbeat)
            if self.own_sync:
                net.unsubscribe(cobid.SYNC, self._on_sync)
            for cob_id, handler in self._rpdo_handlers:
                net.unsubscribe(cob_id, handler)
            self._rpdo_handlers.clear()
            for pdo_map in self.tpdo.map.values():
                if pdo_map.enabled and pdo_map.cob_id:
                    net.unsubscribe(pdo_map.cob_id, pdo_map.on_message)
            if self.id in net.nodes:
                del net[self.id]
            else:
                self.remove_network()

    def _boot(self) -> None:
        self.nmt._state = INITIALISING
        self.network.send_message(cobid.heartbeat(self.id), [0])  # boot-up
        self.nmt._state = PRE_OPERATIONAL
        self._state_changed()

    def _after_reset(self, full: bool) -> None:
        with self._lock:
            self._inbox.discard()
            self._inbox.forget_applied()
            if full:
                self.data_store.clear()
                self._values.clear()
                self.app.on_reset()
            self._agent_last_hb = None
            self._syncs_since_hb = 0
            self._hb_lost = False
        self._boot()

    def _state_changed(self) -> None:
        if self.nmt._state == OPERATIONAL:
            self._hb_lost = False
        self.app.on_nmt_state(self.nmt.state)
        if self.nmt._state == OPERATIONAL:
            self.send_event_tpdos(force=True)

    # -- application state ---------------------------------------------------------------
    def set_value(self, index: int, subindex: int, raw: int) -> None:
        """Telemetry/application value of an object (what SDO uploads and TPDOs carry)."""
        key = (index, subindex)
        if key in self._inbox.keys:  # an RPDO-mapped object: its next frame is compared anew
            self._inbox.forget_applied()
        self._values[key] = raw

    @property
    def values(self) -> dict[Key, int]:
        """The application values by (index, sub-index), live (``set_value`` in bulk: an
        application's ``sample`` fills it while the node's lock is held; RPDO-mapped objects
        are written only by ``apply_commands`` and ``set_value``)."""
        return self._values

    @property
    def synchronous_rpdo_keys(self) -> frozenset[tuple[int, int]]:
        """(index, sub-index) of every object its synchronous RPDOs carry (after ``connect``)."""
        return self._inbox.keys

    def received(self, index: int, subindex: int = 0) -> int | None:
        """The application value of an object if one was set or received, else ``None``."""
        return self._values.get((index, subindex))

    def value(self, index: int, subindex: int = 0) -> int | float | str:
        """Current value: application state, else downloaded data, else the EDS default."""
        key = (index, subindex)
        if key in self._values:
            return self._values[key]
        od = self._find_object(index, subindex)
        return od.decode_raw(self.get_data(index, subindex))

    def reset_application(self) -> None:
        """Power-on state of the application (commands forgotten, defaults back) without an
        NMT reset: what a simulated robot does when it starts a new scenario."""
        with self._lock:
            self._inbox.discard()
            self._inbox.forget_applied()
            for pdo_map in self.rpdo.map.values():
                for var in pdo_map.map:
                    self._values.pop((var.index, var.subindex), None)
            self.app.on_reset()
            self.app.on_nmt_state(self.nmt.state)

    @property
    def operational(self) -> bool:
        return self.nmt._state == OPERATIONAL

    def emergency(self, code: EmcyCode, info: bytes = b"") -> None:
        """Send EMCY ``code`` and keep the error register (0x1001) in step."""
        register = int(EMCY_REGISTER[code])
        self.set_value(Index.ERROR_REGISTER, 0, register)
        self.emcy.send(int(code), register, info[:5].ljust(5, b"\0"))

    # -- SYNC-driven cycle -----------------------------------------------------------------
    def apply_commands(self) -> None:
        """Make the RPDO values received since the last SYNC take effect (the application
        hears of those that changed)."""
        inbox = self._inbox
        if not inbox.pending:
            return
        with self._lock:
            if not self.operational:
                inbox.discard()
                return
            changed = inbox.take(self._values)
        if changed:
            self.app.on_commands(changed)

    @property
    def tpdo_layouts(self) -> tuple[TpdoLayout, ...]:
        """The node's synchronous TPDOs (after ``connect``), in transmission order."""
        return tuple(self._layouts)

    def count_sync(self) -> int:
        """Count this SYNC for the TPDOs' transmission types: the node's SYNC count, 0 when it
        sends no TPDOs (not operational, or taken off the bus by ``close``)."""
        if self.nmt._state != OPERATIONAL or not self.has_network():
            return 0
        self.sync_count += 1
        return self.sync_count

    def due_tpdos(self) -> list[TpdoLayout]:
        """Count this SYNC (``count_sync``) and return the synchronous TPDOs due at it."""
        count = self.count_sync()
        return [layout for layout in self._layouts if layout.due(count)]

    def transmit_tpdos(self) -> None:
        """Sample the application and send every synchronous TPDO due at this SYNC from the
        node's values (a simulated robot samples all its nodes at once instead:
        ``firmware_sim.nodes.sampler``)."""
        due = self.due_tpdos()
        if not due:
            return
        frames: list[tuple[int, bytes]] = []
        with self._lock:
            self.app.sample()
            values = self._values
            for tpdo in due:
                try:
                    data = tpdo.layout.pack(*tpdo.values_of(values))
                except KeyError:  # an object the application never set: stored data / EDS default
                    data = tpdo.layout.pack(*[int(self.value(*k)) for k in tpdo.keys])
                frames.append((tpdo.cob_id, data))
        for cob_id, data in frames:
            self.network.send_message(cob_id, data)

    def _on_sync(self, can_id, data, timestamp) -> None:
        self.apply_commands()
        self.transmit_tpdos()

    def send_event_tpdos(self, force: bool = False) -> None:
        """Send each event-driven TPDO whose data changed since it was last sent, whose event
        timer ran out, or every one with ``force`` (only while operational)."""
        if not self._events or not self.operational or not self.has_network():
            return
        now, frames = time.monotonic(), []
        with self._lock:
            for tpdo in self._events:
                data = tpdo.layout.pack(*[int(self.value(*key)) for key in tpdo.keys])
                last = self._event_sent.get(tpdo.cob_id)
                if (force or last is None or last[0] != data
                        or (tpdo.timer_s and now - last[1] >= tpdo.timer_s)):
                    self._event_sent[tpdo.cob_id] = (data, now)
                    frames.append((tpdo.cob_id, data))
        for cob_id, data in frames:
            try:
                self.network.send_message(cob_id, data)
            except Exception as exc:  # bus gone: the owner is shutting us down
                log.debug("node %#x event TPDO not sent: %s", self.id, exc)

    def _event_rpdo_handler(self, spec):
        """Receive an event-driven RPDO: its values take effect at once (the application hears
        of those that changed)."""
        layout = pdo_struct(spec)
        keys = spec.keys

        def on_frame(can_id, data, timestamp) -> None:
            if not self.operational or len(data) < layout.size:
                return
            with self._lock:
                received = tuple(zip(keys, layout.unpack_from(bytes(data))))
                changed = {key: value for key, value in received if self._values.get(key) != value}
                self._values.update(received)
            if changed:
                self.app.on_commands(changed)
        return on_frame

    def _rpdo_handler(self, slot: int):
        """Receive RPDO ``slot`` of the inbox: its frame kept whole until the SYNC."""
        size, store, lock = self._inbox.sizes[slot], self._inbox.store, self._lock

        def on_frame(can_id, data, timestamp) -> None:
            if not self.operational or len(data) < size:
                return
            frame = bytes(data)
            with lock:
                store(slot, frame)
        return on_frame

    # -- SDO server hooks ------------------------------------------------------------------
    def _on_sdo_read(self, index: int, subindex: int, od) -> int | None:
        live = self.app.read((index, subindex))
        return live if live is not None else self._values.get((index, subindex))

    def _on_sdo_write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = check_range(od, data)
        if value is None:
            value = od.decode_raw(data)
        self.app.on_config((index, subindex), value)

    # -- heartbeat producer and consumer ---------------------------------------------------
    def _on_agent_heartbeat(self, can_id, data, timestamp) -> None:
        self._agent_last_hb = time.monotonic()
        self._syncs_since_hb = 0

    def agent_sync(self) -> None:
        """A SYNC of the agent arrived (lock-step: the plant's clock ticked once)."""
        self._syncs_since_hb += 1

    def _agent_silent(self, now: float, timeout: float) -> bool:
        """The agent's heartbeat has been silent for longer than ``timeout`` on the wall clock;
        in lock-step (``lockstep_period_s``) also for ``timeout`` in SYNC periods, or else for
        ``LOCKSTEP_PATIENCE_S``: a stalled agent sends no SYNC either, and a plant in
        lock-step does not move without one (``protocol.can.lockstep``)."""
        last = self._agent_last_hb
        if last is None or now - last <= timeout:
            return False
        return (self._lockstep_period_s is None or self._syncs_since_hb * self._lockstep_period_s > timeout
                or now - last > max(timeout, LOCKSTEP_PATIENCE_S))

    def consumer_timeout(self) -> float:
        """Seconds of agent silence tolerated (0x1016 sub1, 0 = not monitored)."""
        try:
            word = int(self.value(Index.CONSUMER_HEARTBEAT, 1))
        except (KeyError, SdoAbortedError):
            return 0.0
        if (word >> 16) & 0x7F != AGENT_NODE_ID:
            return 0.0
        return (word & 0xFFFF) / 1000.0

    def _watch(self) -> None:
        while not self._stop.wait(WATCHDOG_TICK_S):
            self.tick(time.monotonic())

    def tick(self, now: float) -> None:
        """One watchdog tick at ``now`` (``time.monotonic``): the heartbeat when due, the
        event-driven TPDOs, the agent's heartbeat checked (see the class doc)."""
        period = int(self.value(Index.PRODUCER_HEARTBEAT, 0)) / 1000.0
        if period > 0 and now >= self._next_hb:
            try:
                self.network.send_message(cobid.heartbeat(self.id), [self.nmt._state])
            except Exception as exc:  # bus gone: the owner is shutting us down
                log.debug("node %#x heartbeat not sent: %s", self.id, exc)
            self._next_hb = now + period
        if self._events:
            self.send_event_tpdos()
        timeout = self.consumer_timeout()
        last = self._agent_last_hb
        if timeout and not self._hb_lost and self._agent_silent(now, timeout):
            self._hb_lost = True
            log.warning("node %#x: agent heartbeat lost (%.0f ms), safe state", self.id,
                        1000 * (now - last))
            self.app.on_heartbeat_lost()
            self.emergency(EmcyCode.HEARTBEAT_LOST)

