"""Process supervision and stack wiring for the commands that run a whole stack (``ersac-hil demo``,
``ersac-hil reproduce``, the benches): :class:`Child` (one process in its own group that dies
with its parent), :class:`Stack` (the router and the simulator/agent pairs, started in order and
stopped in reverse), :func:`busy_poll_for` (the CPU policy of the CAN-over-Zenoh buses)."""
from .cpu import BUSY_POLL_S, busy_poll_for
from .process import GRACE_S, Child, ChildFailed, child_env, cli_argv, die_with_parent
from .wiring import Pair, Stack

__all__ = ["BUSY_POLL_S", "GRACE_S", "Child", "ChildFailed", "Pair", "Stack", "busy_poll_for", "child_env",
           "cli_argv", "die_with_parent"]
