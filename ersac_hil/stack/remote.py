"""Simulator/agent pairs already running elsewhere behind a router (``--agents KEYEXPR``): the
command-line flags of every command that can use them instead of starting pairs (``reproduce``,
``bench/bracing_sweep.py``), their checks, and :class:`RemoteAgents`, the ``Stack`` whose pairs
are those agents (nothing of theirs started or stopped here)."""
from __future__ import annotations

import argparse
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ersac_hil.zenoh_session import ZenohOptions, add_zenoh_arguments, zenoh_argv, zenoh_options
from protocol.zenoh.keys import DEFAULT_PREFIX

from .wiring import Pair, Stack

__all__ = ["AGENT_WAIT_S", "Agents", "RemoteAgents", "add_agents_arguments", "agents_from_args"]

AGENT_WAIT_S = 30.0
"""How long ``--agents`` waits for a matching agent by default."""


@dataclass(frozen=True)
class Agents:
    """``--agents SOURCE`` (a robot name or a one-chunk key expression of names under ``prefix``)
    behind the router that ``options`` reach; ``wait_s``: how long to wait for one to be ready."""

    source: str
    options: ZenohOptions
    wait_s: float = AGENT_WAIT_S
    prefix: str = DEFAULT_PREFIX


def add_agents_arguments(parser: argparse.ArgumentParser) -> None:
    """``--agents KEYEXPR``, ``--agent-wait S`` and the Zenoh flags (``--zenoh``,
    ``--zenoh-config``, ``--insecure``) that reach their router."""
    parser.add_argument("--agents", metavar="KEYEXPR", default=None,
                        help="instead of starting simulator/agent pairs, use those already running behind the "
                        "router of --zenoh/--zenoh-config: the agents of these robots (a name or a one-chunk key "
                        f"expression of names under the prefix {DEFAULT_PREFIX}, e.g. 'ubot$*'); the same results")
    parser.add_argument("--agent-wait", type=float, default=None, metavar="S",
                        help=f"with --agents: how long to wait for a matching agent (default {AGENT_WAIT_S:g} s)")
    add_zenoh_arguments(parser)


def agents_from_args(args: argparse.Namespace) -> tuple[Agents | None, str]:
    """The :func:`add_agents_arguments` flags as :class:`Agents` (``None`` without ``--agents``),
    or the one-line refusal of a combination that does not fit (with ``--pairs``, Zenoh flags
    without ``--agents``, a malformed key expression, a wait out of range)."""
    from ersac_hil.daemon.config import check_source

    options = zenoh_options(args)
    if args.agents is None:
        given = [flag for flag, value in (("--zenoh", options.endpoints), ("--zenoh-config", options.config_file),
                                          ("--insecure", options.insecure), ("--agent-wait", args.agent_wait))
                 if value]
        return None, (f"{', '.join(given)} only with --agents (the router of pairs running elsewhere)"
                      if given else "")
    if getattr(args, "pairs", None) is not None:
        return None, ("--pairs and --agents exclude each other (--pairs starts pairs here, --agents uses "
                      "pairs already running behind a router)")
    try:
        check_source(args.agents)
    except ValueError as exc:
        return None, f"--agents {exc}"
    wait = AGENT_WAIT_S if args.agent_wait is None else args.agent_wait
    if not 0 < wait <= 3600:
        return None, f"--agent-wait must be in (0, 3600] s, got {wait:g}"
    return Agents(args.agents, options, wait), ""


class RemoteAgents(Stack):
    """Simulator/agent pairs already running elsewhere behind a router: the agents of ``robots``
    under ``prefix`` (``ersac_hil.daemon.discovery.reach_agents`` found them) are the pairs; no
    process of theirs is started or stopped here. The children launched here (the
    daemons of ``reproduce``) and this process's sessions connect with ``options`` (the user's
    ``--zenoh``, ``--zenoh-config``, ``--insecure``: one identity for all)."""

    def __init__(self, logs: Path, stop: threading.Event, say: Callable[[str], None], robots: Sequence[str],
                 prefix: str, options: ZenohOptions) -> None:
        super().__init__(logs, stop, say, pairs=0)
        self.options = options
        self.endpoint = " ".join(options.endpoints) or str(options.config_file)
        self.pairs = [Pair(robot, prefix, "", None, None) for robot in robots]

    def zenoh_options(self) -> ZenohOptions:
        return self.options

    def zenoh_args(self, role: str, bind: str | None = None) -> list[str]:
        """The user's Zenoh flags, whatever the role (the identity of the config file)."""
        return zenoh_argv(self.options)

    def start(self) -> RemoteAgents:
        """Nothing to start: the pairs are running."""
        return self
