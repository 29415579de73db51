"""Print what crosses the bus, decoded by COB-ID (for ``ersac-hil bus --monitor``)."""
from __future__ import annotations

import threading

import can

from protocol.can.devices import DEVICES
from protocol.can.busconfig import BusConfig, open_bus
from protocol.can.cobid import classify

_NAMES = {d.node_id: d.name for d in DEVICES} | {1: "agent"}


def describe(msg: can.Message) -> str:
    info = classify(msg.arbitration_id)
    who = "" if info.node_id is None else f" {_NAMES.get(info.node_id, hex(info.node_id))}"
    return f"{msg.arbitration_id:03X} {info.function:<9}{who:<11} [{msg.dlc}] {msg.data.hex(' ')}"


class BusMonitor:
    def __init__(self, config: BusConfig, out=print) -> None:
        self._config, self._out = config, out
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames = 0

    def start(self) -> "BusMonitor":
        self._bus = open_bus(self._config)
        self._thread = threading.Thread(target=self._run, name="bus-monitor", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(0.1)
            if msg is not None:
                self.frames += 1
                self._out(describe(msg))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        self._bus.shutdown()
