"""Liveness in lock-step, the one fact both sides of the bus agree on.

In lock-step the simulated robot's clock is the SYNC counter: physics advances one control
period per SYNC and nothing moves between SYNCs. A loaded machine may stall the simulator or
the agent for longer than a real robot's deadlines (a TPDO within 250 ms, a heartbeat within
0.6 s, the controllers' 250 ms consumer time); a stalled process is late, not gone. So in
lock-step a silence counts as a loss only once it also lasted :data:`LOCKSTEP_PATIENCE_S` on
the wall clock (or, for the controllers' watchdog, the consumer time in SYNC periods while
SYNCs still come). Real time keeps the robot's deadlines.
"""
from __future__ import annotations

__all__ = ["LOCKSTEP_PATIENCE_S"]

LOCKSTEP_PATIENCE_S = 5.0
"""Seconds of silence after which a node (agent side) or the agent (controller side) is lost
in lock-step."""
