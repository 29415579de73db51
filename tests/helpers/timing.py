"""Patient timing for tests about what an episode does, not about how fast a fault is noticed.

A loaded machine can stall a process for longer than the product's defaults allow (a TPDO
250 ms late, the agent's heartbeat 250 ms late at a controller): such a test then fails with a
fault it does not test. The tests of the faults themselves keep the defaults; bench/ measures
how fast faults are noticed.
"""
from __future__ import annotations

from collections.abc import Iterable

import canopen

from ersac_hil.agent.bus import BusTiming
from protocol.can.devices import AGENT_NODE_ID
from protocol.can.objects import Index

PATIENCE_MS = 5000
PATIENCE_S = PATIENCE_MS / 1000
"""Also how long a test waits for nodes it just started to send their first heartbeat (the
agent's own check, ``AgentBus.wait_for_nodes``, allows two heartbeat periods)."""
PATIENT = BusTiming(deadline_s=PATIENCE_S, heartbeat_timeout_s=PATIENCE_S)
"""The agent waits this long for a TPDO or a node's heartbeat."""
PATIENT_AGENT_FLAGS = ("--deadline-ms", str(PATIENCE_MS), "--heartbeat-timeout-ms", str(PATIENCE_MS))
"""The same for an ``ersac-hil agent`` process."""
PATIENT_CONSUMER = AGENT_NODE_ID << 16 | PATIENCE_MS
"""Object 0x1016 sub 1: the controllers tolerate this much silence of the agent's heartbeat."""


def patient_sdo(nodes: Iterable[canopen.RemoteNode]) -> None:
    """SDO clients that wait ``PATIENCE_MS`` for an answer (canopen's default is 0.3 s)."""
    for node in nodes:
        node.sdo.RESPONSE_TIMEOUT = PATIENCE_MS / 1000


def patient_controllers(nodes: Iterable[canopen.RemoteNode]) -> None:
    """Write ``PATIENT_CONSUMER`` into every node's consumer heartbeat time by SDO."""
    for node in nodes:
        node.sdo[Index.CONSUMER_HEARTBEAT][1].raw = PATIENT_CONSUMER
