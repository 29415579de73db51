"""The test's side of a CAN bus: reference nodes, a master, frame logs, barriers.

* ``ReferenceNodes`` - every device as a ``SlaveNode`` with the static application (what
  the EDS files say and nothing more), on its own network.
* ``Master`` - a canopen network with a ``RemoteNode`` per device, built from the EDS files.
* ``FrameLog`` - every frame of some COB-IDs in arrival order; wait for a condition on them;
  ``heartbeats``/``reported``/``set_state`` for NMT states as the nodes report them.
* ``SdoTrace`` - the SDO frames both sides received, for the report of a test that failed.
* ``sdo_barrier`` - an SDO round trip to each node: everything a node sent before its answer
  has been dispatched on the master's side when it returns (frames of one sender arrive and
  are dispatched in order), so "nothing arrived" can be asserted without sleeping.
* ``at_sync`` - run an action in the bus's own SYNC dispatch once a condition holds: a fault
  injected at an exact simulated time instead of whenever a polling thread gets to it.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

import canopen
from canopen.nmt import NMT_STATES

from firmware_sim.nodes import SlaveNode
from protocol.can import cobid
from protocol.can.devices import DEVICES, Device, object_dictionary
from protocol.can.busconfig import BusConfig, open_network

from helpers.timing import PATIENCE_S, patient_sdo
from helpers.waiting import DEFAULT_TIMEOUT_S

Frame = tuple[int, bytes]


class ReferenceNodes:
    """Every device of ``devices`` as a ``SlaveNode`` with the static application."""

    def __init__(self, bus_config: BusConfig, devices: tuple[Device, ...] = DEVICES) -> None:
        self.devices = tuple(devices)
        self.network = open_network(bus_config)
        self.nodes = {d.name: SlaveNode(d) for d in self.devices}
        for node in self.nodes.values():
            node.connect(self.network)

    def remove(self, name: str) -> None:
        """Take one node off the bus (it stops answering, sending TPDOs and heartbeats)."""
        self.nodes.pop(name).close()

    def close(self) -> None:
        for node in self.nodes.values():
            node.close()
        self.network.disconnect()


class Master:
    """The test's CANopen master: a ``RemoteNode`` per device on its own network, ready once it
    has heard every device's heartbeat (as the agent's ``AgentBus.wait_for_nodes``).

    Over Zenoh that wait is what makes the first command arrive: a session sends a frame only
    to the subscriptions it has been told of, so a frame sent right after the bus opened can
    miss buses that are already there (47 of 100 sends right after the receiving bus opened,
    none after the sender heard it; the NMT and SDO tests' rare "never answered" beside CPU
    hogs). A node's heartbeat travels after its subscription, so hearing it proves the master's
    frames reach that node, and its answers the master."""

    def __init__(self, bus_config: BusConfig, devices: Iterable[Device]) -> None:
        self.network = open_network(bus_config)
        self.devices = {d.name: d for d in devices}
        log = heartbeats(self.network, self.devices.values())
        try:
            self.nodes = {d.name: self.network.add_node(d.node_id, object_dictionary(d))
                          for d in self.devices.values()}
            patient_sdo(self.nodes.values())  # an answer late on a loaded machine is still an answer
            for d in self.devices.values():
                beat = cobid.heartbeat(d.node_id)
                log.wait_for(lambda frames, beat=beat: any(f[0] == beat for f in frames), PATIENCE_S,
                             what=f"{d.name}'s heartbeat at the test's master")
        except BaseException:
            self.network.disconnect()
            raise
        finally:
            log.close()

    def close(self) -> None:
        self.network.disconnect()


class FrameLog:
    """Every frame with one of ``cob_ids`` that ``network`` receives, in arrival order, with
    when its dispatch reached this log (``times``, ``time.monotonic()``)."""

    def __init__(self, network: canopen.Network, cob_ids: Iterable[int]) -> None:
        self.network, self.cob_ids = network, tuple(cob_ids)
        self.frames: list[Frame] = []
        self.times: list[float] = []
        self._cond = threading.Condition()
        for cob in self.cob_ids:
            network.subscribe(cob, self._on_frame)

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = time.monotonic()
        with self._cond:
            self.frames.append((can_id, bytes(data)))
            self.times.append(now)
            self._cond.notify_all()

    def longest_silence(self, cob_id: int, until: float) -> float:
        """The longest time (s) between two arrivals of ``cob_id``, or from its last arrival
        to ``until`` (a ``time.monotonic()``); infinite if it never arrived."""
        with self._cond:
            arrivals = [t for (c, _), t in zip(self.frames, self.times) if c == cob_id] + [until]
        return max((b - a for a, b in zip(arrivals, arrivals[1:])), default=float("inf"))

    def count(self, cob_id: int) -> int:
        with self._cond:
            return sum(1 for c, _ in self.frames if c == cob_id)

    def counts(self) -> dict[int, int]:
        with self._cond:
            return {c: sum(1 for f, _ in self.frames if f == c) for c in self.cob_ids}

    def wait_for(self, predicate: Callable[[list[Frame]], object], timeout_s: float = DEFAULT_TIMEOUT_S,
                 what: str = "frames") -> object:
        """Block until ``predicate(frames)`` is truthy (woken by every new frame); raise
        ``TimeoutError`` naming ``what`` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                value = predicate(self.frames)
                if value:
                    return value
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"{what} not received within {timeout_s} s")
                self._cond.wait(remaining)

    def close(self) -> None:
        for cob in self.cob_ids:
            self.network.unsubscribe(cob, self._on_frame)


class SdoTrace:
    """The SDO frames of ``devices`` as the master's network and the nodes' network receive
    them, so that a test an SDO answer never reached can say which way the frame was lost:
    a request the nodes never received, or an answer the master never received."""

    def __init__(self, master: canopen.Network, nodes: canopen.Network, devices: Iterable[Device]) -> None:
        cobs = [c for d in devices for c in (cobid.sdo_rx(d.node_id), cobid.sdo_tx(d.node_id))]
        self.start = time.monotonic()
        self.logs = {"master": FrameLog(master, cobs), "nodes": FrameLog(nodes, cobs)}

    def describe(self, last: int = 24) -> str:
        """The last ``last`` frames of both sides in time order, one a line: ms since the
        start, which side received it, COB-ID, the first four data bytes (command, index,
        subindex)."""
        rows = sorted((t, side, can_id, data[:4].hex(" "))
                      for side, log in self.logs.items()
                      for (can_id, data), t in zip(list(log.frames), list(log.times)))
        lines = [f"{1000 * (t - self.start):9.1f} ms  {side:6} received {can_id:#05x} {data}"
                 for t, side, can_id, data in rows[-last:]]
        return "\n".join(lines) or "no SDO frame received by either side"

    def close(self) -> None:
        for log in self.logs.values():
            log.close()


def heartbeats(network: canopen.Network, devices: Iterable[Device]) -> FrameLog:
    return FrameLog(network, [cobid.heartbeat(d.node_id) for d in devices])


def reported(node_id: int, state: str, after: int = 0) -> Callable[[list[Frame]], int | None]:
    """Predicate on a heartbeat log: ``node_id`` reported ``state`` ("INITIALISING" is the
    boot-up) at position ``after`` or later; returns that position + 1."""
    def check(frames: list[Frame]) -> int | None:
        for i in range(after, len(frames)):
            can_id, data = frames[i]
            if can_id == cobid.heartbeat(node_id) and data and NMT_STATES.get(data[0] & 0x7F) == state:
                return i + 1
        return None
    return check


def set_state(network: canopen.Network, devices: Iterable[Device], state: str) -> None:
    """Broadcast the NMT command for ``state`` and wait until every device's heartbeat reports it."""
    devices = tuple(devices)
    log = heartbeats(network, devices)
    try:
        network.nmt.state = state
        for d in devices:
            log.wait_for(reported(d.node_id, state), what=f"{d.name} heartbeat reporting {state}")
    finally:
        log.close()


def sdo_barrier(nodes: Iterable[canopen.RemoteNode]) -> None:
    """One SDO upload (device type, 0x1000) from each node."""
    for node in nodes:
        node.sdo.upload(0x1000, 0)


def at_sync(network: canopen.Network, when: Callable[[], bool], action: Callable[[], None]) -> threading.Event:
    """Call ``action`` once, from the SYNC dispatch of ``network``, at the first SYNC after which
    ``when()`` holds. Subscribers run in subscription order, so on a simulated robot's network
    this runs right after the robot stepped its physics for that SYNC. Returns an event set
    once the action ran."""
    done = threading.Event()

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        if not done.is_set() and when():
            done.set()
            action()

    network.subscribe(cobid.SYNC, on_sync)
    return done
