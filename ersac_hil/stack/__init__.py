"""Process supervision and stack wiring for the commands that run a whole stack (``ersac-hil demo``,
``ersac-hil reproduce``, the benches): :class:`Child` (one process in its own group that dies
with its parent), :class:`Stack` (the router and the simulator/agent pairs, started in order and
stopped in reverse), :func:`busy_poll_for` (the CPU policy of the CAN-over-Zenoh buses);
``stack.remote``: pairs already running elsewhere behind a router (``--agents``)."""
from .cpu import BUSY_POLL_S, PAIRS_PER_CORE, TooManyPairs, busy_poll_for, check_pairs, max_pairs, usable_cores
from .process import GRACE_S, Child, ChildFailed, child_env, cli_argv, die_with_parent
from .wiring import Pair, Stack

__all__ = ["BUSY_POLL_S", "GRACE_S", "PAIRS_PER_CORE", "Child", "ChildFailed", "Pair", "Stack", "TooManyPairs",
           "busy_poll_for", "check_pairs", "child_env", "cli_argv", "die_with_parent", "max_pairs", "usable_cores"]
