"""The agent's heartbeat producer (node ``AGENT_NODE_ID``) on its own timer.

python-can-remote 0.3's periodic tasks cannot change their data (its
``CyclicSendTask.modify_data`` calls ``super(self)`` and raises TypeError, so canopen's
heartbeat producer would keep reporting the old NMT state over a remote bus), so the agent
sends its heartbeat from a thread, reporting the state the caller gives. A send that fails
(the bus down for a while) is said once and the beat goes on.
"""
from __future__ import annotations

import logging
import threading

import can
import canopen

from protocol.can import cobid
from protocol.can.devices import AGENT_NODE_ID, HEARTBEAT_PERIOD_MS
from protocol.can.nmt import OPERATIONAL


log = logging.getLogger(__name__)


class HeartbeatProducer:
    def __init__(self, network: canopen.Network, node_id: int = AGENT_NODE_ID,
                 period_s: float = HEARTBEAT_PERIOD_MS / 1000.0, state: int = OPERATIONAL) -> None:
        self._network, self._cob, self._period = network, cobid.heartbeat(node_id), period_s
        self.state = state
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "HeartbeatProducer":
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="agent-heartbeat", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def frame(self) -> tuple[int, bytes]:
        """The heartbeat as a ``(COB-ID, data)`` frame, for a caller that sends it itself (the
        agent's lock-step SYNC cycle)."""
        return self._cob, bytes([self.state])

    def _run(self) -> None:
        failing = False
        while True:
            try:
                self._network.send_message(self._cob, [self.state])
            except (can.CanError, OSError) as exc:  # the bus is down for now: keep beating
                if not failing:
                    log.warning("agent heartbeat not sent: %s", exc)
                failing = True
            else:
                failing = False
            if self._stop.wait(self._period):
                return

    def __enter__(self) -> "HeartbeatProducer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
