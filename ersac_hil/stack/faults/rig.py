"""The rig a fault hits: router, simulator, agent and daemon of one learning run, each a child
process of its own, started and stopped one by one."""
from __future__ import annotations

import os
import re
import resource
import signal
import time
from collections.abc import Sequence
from pathlib import Path

from ersac_hil.zenoh_session import free_tcp_port

from ..process import Child, child_env, cli_argv
from .history import History, history
from .netns import Netns

__all__ = ["ROBOT", "START_S", "TASK", "Rig", "reference_run"]

ROBOT = "ubot1"
TASK = "bracing"
START_S = 120.0
"""How long a child may take to come up (a loaded machine starts MuJoCo slowly)."""


class Rig:
    """Router, simulator, agent and daemon of one learning run as separate child processes
    (``ersac_hil.stack.Child``: own process group, log file, killed with this process), each
    started and stopped on its own, so that a fault can hit any of them.

    The router's endpoint is fixed at construction (a restarted router listens where the
    sessions reconnect). With ``netns``, the daemon runs in its namespace and the simulator and
    agent in the robot's; the router beside the robot (``router_beside="robot"``: the daemon
    connects over the veth) or beside the daemon (``"daemon"``: the agent connects over it).

    Args:
        work: directory of the store (``work/run.db``) and the children's logs.
        seed: the run's seed (daemon ``--seed``; the simulator's base seed too).
        episodes: the run's budget.
        netns: run across this namespace pair.
        router_beside: with ``netns``, the namespace of the router.
    """

    def __init__(self, work: Path, seed: int, episodes: int, netns: Netns | None = None,
                 router_beside: str = "robot") -> None:
        self.work, self.seed, self.episodes, self.netns = work, seed, episodes, netns
        self.router_beside = router_beside
        self.db = work / "run.db"
        self.logs = work / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        host = (Netns.ROBOT_IP if router_beside == "robot" else Netns.DAEMON_IP) if netns else "127.0.0.1"
        self.endpoint = f"tcp/{host}:{free_tcp_port()}"
        self.can_channel = ""
        """The simulator/agent CAN-over-Zenoh channel (``name@endpoint`` of the simulator's listener)."""
        self.children: dict[str, Child] = {}
        self.pids: list[int] = []
        """Every child process ever started."""
        self.said: list[tuple[float, str, str]] = []
        """(``time.monotonic()``, child, line) of every output line of every child, in order."""
        self._env = child_env()
        self._starts: dict[str, int] = {}

    def _launch(self, name: str, argv: Sequence[str], ns: str | None) -> Child:
        n = self._starts[name] = self._starts.get(name, 0) + 1
        prefix = self.netns.prefix(ns) if self.netns and ns else []
        child = Child(name if n == 1 else f"{name}-{n}", [*prefix, *argv], self.logs, self._env,
                      echo=lambda line: self.said.append((time.monotonic(), name, line)))
        self.children[name] = child
        self.pids.append(child.pid)
        return child

    def first_line(self, name: str, since: float, pattern: str) -> float | None:
        """When ``name`` (any of its starts) first printed a line matching ``pattern`` after ``since``."""
        regex = re.compile(pattern)
        return next((t for t, who, line in list(self.said) if who == name and t > since and regex.search(line)), None)

    def output(self, name: str = "daemon") -> str:
        """Everything ``name`` printed, over all its starts."""
        return "\n".join(line for _, who, line in list(self.said) if who == name)

    def _robot_ns(self) -> str | None:
        return self.netns.robot if self.netns else None

    def _daemon_ns(self) -> str | None:
        return self.netns.daemon if self.netns else None

    @property
    def cut_off(self) -> str:
        """The namespace a partition cuts off from the router: the one without it."""
        return "daemon" if self.router_beside == "robot" else "robot"

    def start_router(self) -> Child:
        insecure = ["--insecure"] if self.netns else []
        router = self._launch("router", cli_argv("router", "--zenoh", self.endpoint, *insecure),
                              self._robot_ns() if self.router_beside == "robot" else self._daemon_ns())
        router.wait_for(r"Zenoh router: ", START_S)
        return router

    def start_robot(self) -> None:
        """Simulator, then the agent, its CAN over Zenoh on a direct link to the simulator."""
        listen = f"tcp/127.0.0.1:{free_tcp_port()}"
        bus = f"ersac-{ROBOT}"
        self.can_channel = f"{bus}@{listen}"
        sim = self._launch("sim", cli_argv("sim", "--bus-interface", "zenoh", "--bus-channel", bus,
                                           "--bus-kwargs", f"listen={listen}", "--seed", str(self.seed)),
                           self._robot_ns())
        sim.wait_for(r"^simulator: \d+ nodes", START_S)
        insecure = ["--insecure"] if self.netns else []
        self._launch("agent", cli_argv("-v", "agent", "--robot", ROBOT, "--bus-interface", "zenoh", "--bus-channel",
                                       self.can_channel, "--zenoh", self.endpoint, *insecure),
                     self._robot_ns()).wait_for(r"^agent ready: ", START_S)

    def start_daemon(self) -> Child:
        """The daemon: a new run on an empty store, else it resumes the store's unfinished run."""
        insecure = ["--insecure"] if self.netns else []
        return self._launch("daemon", cli_argv(
            "daemon", "--robot", ROBOT, "--task", TASK, "--episodes", str(self.episodes), "--seed", str(self.seed),
            "--kappa", "2", "--zenoh", self.endpoint, *insecure, "--db", str(self.db), "--backoff", "0.05,0.5",
            "--agent-wait", "300"), self._daemon_ns())

    def start(self) -> Rig:
        self.start_router()
        self.start_robot()
        self.start_daemon()
        return self

    def kill(self, *names: str) -> None:
        """SIGKILL the process groups of ``names`` (default: every child) at once, the daemon's
        first: it is the store's only writer, so the store is left as a power loss leaves it
        (killed last, it had time on a loaded machine, between the kills, to see the router and
        agent vanish and store the running attempt ``lost``)."""
        order = sorted(names or list(self.children), key=lambda name: name != "daemon")
        for name in order:
            child = self.children.get(name)
            if child is not None and child.alive():
                os.killpg(child.pid, signal.SIGKILL)
        for name in order:
            child = self.children.pop(name, None)
            if child is not None:
                child.stop(0)

    def limit_file_size(self, name: str, size: int) -> None:
        """``RLIMIT_FSIZE`` of the running ``name``: no file it writes grows past ``size`` bytes
        (the disk is full for it); Python ignores SIGXFSZ, so a write fails with EFBIG."""
        resource.prlimit(self.children[name].pid, resource.RLIMIT_FSIZE, (size, size))

    def daemon_exit(self, timeout_s: float) -> int:
        """The daemon's exit status (it must end by itself within ``timeout_s``)."""
        daemon = self.children["daemon"]
        code = daemon.proc.wait(timeout_s)
        daemon.stop(0)
        return code

    def close(self) -> None:
        """Stop every child: the daemon first, then the robot side, then the router."""
        for name in ("daemon", "agent", "sim", "router"):
            child = self.children.pop(name, None)
            if child is not None:
                child.stop()
        self.kill()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def reference_run(work: Path, seed: int, episodes: int, timeout_s: float) -> History:
    """The run without any fault, to its end."""
    with Rig(work, seed, episodes).start() as rig:
        code = rig.daemon_exit(timeout_s)
        assert code == 0, rig.output()
    h = history(rig.db)
    assert h is not None and h.status == "finished"
    return h

