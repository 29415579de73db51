"""The robot side of a stack as child processes: the Zenoh router and the simulator/agent pairs
(``ersac-hil demo`` and ``ersac-hil reproduce``), their command lines, their order of start and stop."""
from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from protocol.zenoh.keys import DEFAULT_PREFIX

from .cpu import busy_poll_for
from .process import GRACE_S, Child, ChildFailed, child_env, cli_argv

if TYPE_CHECKING:
    from ersac_hil.zenoh_session import ZenohOptions

__all__ = ["Pair", "Stack"]


@dataclass(frozen=True)
class Pair:
    """One simulator/agent pair on its own CAN channel; its agent serves ``robot`` under
    the key prefix ``prefix`` (several pairs: one prefix each, so a run of robot ``robot``
    can go to any of them). ``sim``/``agent``: their processes, ``None`` for a pair that runs
    elsewhere (``remote.RemoteAgents``)."""

    robot: str
    prefix: str
    channel: str
    sim: Child | None
    agent: Child | None


class Stack:
    """The router and ``pairs`` simulator/agent pairs as child processes (the robot side of
    ``ersac-hil demo`` and ``ersac-hil reproduce``); :meth:`launch` adds more children (daemons),
    :meth:`close` stops every child in reverse order.

    Args:
        logs: directory of the children's ``<name>.log`` (certificates go next to it).
        stop: set to interrupt waits (Ctrl-C).
        say: progress lines.
        robot: the robot name every agent serves.
        seed: base seed of the simulators.
        pairs: number of simulator/agent pairs (pair k > 1: prefix ``ersac<k>``, or with
            ``fleet`` robot ``<robot>-<k>`` under the one prefix ``ersac``).
        fleet: name the pairs' robots apart under one prefix (a fleet behind one daemon)
            instead of one robot under several prefixes (independent runs, ``reproduce``).
        secure: TLS with client certificates and the roles' access control
            (``ersac-hil certs init <logs>/../certs``); ``zenoh_args(role)`` gives each role's flags.
        router_host: loopback address the router listens on.
        agent_host: loopback source address of the agents' Zenoh links (``#bind=``).
        can: ``direct`` (CAN over Zenoh, the agent's bus connected to the simulator's listener;
            the agent starts once its simulator is up), ``zenoh`` (through the router; with
            ``secure``, the simulator and the agent on it with their roles' certificates) or ``hub``.
        busy_poll: seconds the simulators' and agents' CAN-over-Zenoh buses keep polling after
            each sample (``ZenohBus(busy_poll=...)``; 0: off; ``None``: :func:`busy_poll_for`).
        series: the agents write every episode's time series there (``agent --record-series``).
        agent_args: further flags of every agent (``demo --ros2``: ``--ros2 --record DIR``).
        description: ``--description`` of every simulator and agent (``None``: their default).
    """

    def __init__(self, logs: Path, stop: threading.Event, say: Callable[[str], None] = print,
                 robot: str = "ubot1", seed: int = 1, pairs: int = 1, secure: bool = False,
                 router_host: str = "127.0.0.1", agent_host: str | None = None, can: str = "direct",
                 fleet: bool = False, busy_poll: float | None = None, series: Path | None = None,
                 agent_args: Sequence[str] = (), description: str | None = None) -> None:
        from ersac_hil.zenoh_session import free_tcp_port

        self.logs, self.stop, self.say, self.robot = logs, stop, say, robot
        self.env = child_env()
        self.children: list[Child] = []
        self.pairs: list[Pair] = []
        self.endpoint = f"{'tls' if secure else 'tcp'}/{router_host}:{free_tcp_port(router_host)}"
        self.roles: dict[str, str] = {}
        self._seed, self._n, self._secure, self._agent_host = seed, pairs, secure, agent_host
        self._fleet = fleet
        self._can = can
        self._series = ["--record-series", str(series)] if series is not None else []
        self._series += list(agent_args)
        self._description = [] if description is None else ["--description", description]
        self._busy_poll = busy_poll_for(pairs) if busy_poll is None else busy_poll
        logs.mkdir(parents=True, exist_ok=True)

    def zenoh_options(self) -> ZenohOptions:
        """How a session of this process (the caller's, a control-plane client's) reaches the router."""
        from ersac_hil.zenoh_session import ZenohOptions
        return ZenohOptions((self.endpoint,))

    def zenoh_args(self, role: str, bind: str | None = None) -> list[str]:
        """``--zenoh`` (and with ``secure``, ``--zenoh-config``) of a child in ``role``."""
        ep = self.endpoint if bind is None or role == "router" else f"{self.endpoint}#bind={bind}:0"
        return ["--zenoh", ep, *(["--zenoh-config", self.roles[role]] if self.roles else [])]

    def can_args(self, role: str, channel: str, bind: str | None = None) -> list[str]:
        """The CAN-over-Zenoh bus flags of a child in ``role`` on ``channel`` (``name@endpoint``):
        from ``bind`` if given, with the role's identity (``--bus-kwargs zenoh_config=``) if
        ``secure``."""
        if bind is not None:
            channel = f"{channel}#bind={bind}:0"
        return ["--bus-interface", "zenoh", "--bus-channel", channel, *self._bus_kwargs(role)]

    def _bus_kwargs(self, role: str, *first: str) -> list[str]:
        """``--bus-kwargs`` of a CAN-over-Zenoh bus in ``role``: ``first``, the role's identity
        (``secure``) and the busy polling (none if empty)."""
        kwargs = [*first, *([f"zenoh_config={self.roles[role]}"] if self.roles else []),
                  *([f"busy_poll={self._busy_poll}"] if self._busy_poll else [])]
        return ["--bus-kwargs", *kwargs] if kwargs else []

    def launch(self, name: str, argv: list[str], echo: Callable[[str], None] | None = None) -> Child:
        """Start ``name`` (``ChildFailed`` instead once ``stop`` is set: nothing starts after Ctrl-C)."""
        if self.stop.is_set():
            raise ChildFailed(f"{name}: interrupted before it started")
        child = Child(name, argv, self.logs, self.env, echo)
        self.children.append(child)
        return child

    def start(self) -> Stack:
        """Certificates (secure), router, then per pair: (hub,) simulator, agent (``direct``: once
        the simulator listens). Raises ``ChildFailed``."""
        from ersac_hil.zenoh_session import free_tcp_port

        if self._secure:
            from ersac_hil.certs import init_certs
            made = init_certs(self.logs.parent / "certs", router=(self.endpoint,), force=True)
            self.roles = {role: str(path) for role, path in made.configs.items()}
        self.launch("router", cli_argv("router", *self.zenoh_args("router"))).wait_for(
            r"Zenoh router: ", 20, self.stop)
        sims = []
        for k in range(1, self._n + 1):
            tag = "" if self._n == 1 else str(k)
            prefix = DEFAULT_PREFIX if k == 1 or self._fleet else f"{DEFAULT_PREFIX}{k}"
            robot = self.robot if k == 1 or not self._fleet else f"{self.robot}-{k}"
            if self._can == "hub":
                hub_port = free_tcp_port()
                channel = f"ws://127.0.0.1:{hub_port}/"
                self.launch(f"hub{tag}", cli_argv("bus", "--port", str(hub_port))).wait_for(
                    r"CAN hub: ws://", 20, self.stop)
                bus = ["--bus-interface", "remote", "--bus-channel", channel]
                sim_bus = agent_bus = bus
            elif self._can == "direct":
                sim_bus, channel = self._direct_listener(f"{prefix}-{robot}")
                agent_bus = self.can_args("agent", channel, self._agent_host)
            else:
                channel = f"{prefix}-{robot}@{self.endpoint}"
                sim_bus, agent_bus = self.can_args("simulator", channel), self.can_args(
                    "agent", channel, self._agent_host)
            sim = self.launch(f"sim{tag}", cli_argv("sim", *sim_bus, "--seed", str(self._seed + k - 1),
                                                    *self._description))
            sims.append((tag, prefix, robot, channel, sim, agent_bus))
        for tag, prefix, robot, channel, sim, agent_bus in sims:
            if self._can == "direct":  # the agent's bus connects to the simulator's listener
                sim.wait_for(r"^simulator: \d+ nodes", 60, self.stop)
            agent = self.launch(f"agent{tag}", cli_argv("agent", "--robot", robot, "--prefix", prefix,
                                                        *agent_bus, *self.zenoh_args("agent", self._agent_host),
                                                        *self._series, *self._description))
            self.pairs.append(Pair(robot, prefix, channel, sim, agent))
        return self

    def _direct_listener(self, name: str) -> tuple[list[str], str]:
        """The simulator's bus flags listening on a free port of the router's host (``tls`` with
        the simulator's certificate and the roles' access control if ``secure``) and the channel
        (``name@endpoint``) the agent connects to."""
        from ersac_hil.zenoh_session import free_tcp_port, split_endpoint

        protocol, host, _ = split_endpoint(self.endpoint)
        listen = f"{protocol}/{host}:{free_tcp_port(host)}"
        return (["--bus-interface", "zenoh", "--bus-channel", name, *self._bus_kwargs("simulator", f"listen={listen}")],
                f"{name}@{listen}")

    def check(self, children: Sequence[Child] | None = None) -> None:
        """``ChildFailed`` if a simulator or an agent (or one of ``children``) has exited."""
        watched = [c for p in self.pairs for c in (p.sim, p.agent)] if children is None else children
        for child in filter(None, watched):
            if not child.alive():
                raise ChildFailed(f"{child.name} exited with {child.proc.returncode}; see {child.log_path}")

    def close(self) -> None:
        """Stop every child: all but the router at once (SIGTERM to each, newest first, then
        SIGKILL to those still running after one common grace period), then the router, so
        the others close their sessions while it still routes; report unexpected exit codes."""
        children = list(reversed(self.children))
        router = [c for c in children if c.name == "router"]
        for wave in ([c for c in children if c not in router], router):
            for child in wave:
                child.terminate()
            deadline = time.monotonic() + GRACE_S
            for child in wave:
                rc = child.stop(deadline - time.monotonic())
                if rc not in (0, None, -signal.SIGTERM, 128 + signal.SIGTERM, 128 + signal.SIGINT):
                    self.say(f"{child.name} exited with {rc} (log {child.log_path})")
        self.children = []

    def __enter__(self) -> Stack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
