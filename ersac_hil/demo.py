"""``ersac-hil demo``: the whole stack on loopback, one learning run, a report, clean shutdown.

Child processes, each in its own process group, started in this order and stopped in the
reverse order (SIGTERM, then SIGKILL after a grace period; also on Ctrl-C/SIGTERM of the demo,
and they get SIGTERM if the demo itself dies, via PR_SET_PDEATHSIG)::

    router   ersac-hil router --port P                      embedded Zenoh router
    sim      ersac-hil sim --bus-interface zenoh --bus-channel ersac-R@tcp/127.0.0.1:P --seed N
    agent    ersac-hil agent --robot R --bus-interface zenoh --bus-channel ... --zenoh tcp/127.0.0.1:P
    daemon   ersac-hil daemon --robot R --task T --kappa K --episodes E --zenoh ... --db OUT/demo.db --new

The CAN bus of each simulator/agent pair is CAN over Zenoh on a direct link (``--can direct``,
the default): the simulator's bus listens on a free port of the router's address
(``--bus-kwargs listen=tcp/127.0.0.1:Q``, ``ersac_hil.canbus.direct``) and the agent's bus
connects to it, one router hop less each way; with ``--secure`` the listener is
``tls/...:Q`` with the simulator's certificate, client certificates required and the router's
access control (only the agent and simulator roles on ``can/**``). ``--can zenoh`` carries it
through the router instead (with ``--secure`` over TLS too, the simulator with the
``simulator`` role's certificate and the agent with the agent's, ``--bus-kwargs
zenoh_config=OUT/certs/<role>.json5``); ``--can hub`` puts it on a python-can-remote loopback
hub (``ersac-hil bus --port H``) per pair. ``Stack`` starts and stops the router and
the simulator/agent pairs (``ersac-hil reproduce`` uses it too, with several pairs). The
daemon's progress lines are shown as they come; every child's output is kept in
``OUT/logs/<name>.log``. When the daemon has finished, the report (``ersac-hil report``) is
written to ``OUT`` and its location printed.

``--secure``: ``ersac-hil certs init OUT/certs`` first; the router listens on
``tls/127.0.0.1:P`` with client certificates and the roles' access control, and every child
connects with its role's config (``--zenoh-config OUT/certs/<role>.json5``).
``OUT/stack.json`` says where the router is and which config each role uses, so a person or a
program can attach (e.g. ``ersac-hil state --zenoh-config OUT/certs/observer.json5``).
``--linger`` keeps the whole stack up after the report until Ctrl-C.
``--busy-poll S``: the simulators' and agents' CAN-over-Zenoh buses keep polling for the next
frame S seconds after each one instead of sleeping (a core per bus while episodes run; 0 turns
it off); by default 0.002 where the machine has a core for each polling bus (two per pair),
else off (``busy_poll_for``).
``--dashboard``: ``ersac-hil dashboard`` starts after the agent, before the daemon (so its page
sees every episode), with the operator's identity under ``--secure``; its URL is printed.
``--fleet N``: N simulator/agent pairs (robots R, R-2, ..., R-N, each pair on its own CAN
channel) behind the one daemon (``--robot R --robot R-2 ...``), which evaluates ``--batch``
perturbations per update in parallel (default N; ``--batch 1`` is the paper's algorithm, one
episode at a time).
"""
from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ersac_hil.cli_args import (UsageError, finite_float, non_negative_float, non_negative_int, output_dir,
                                positive_int, tcp_port)

__all__ = ["register", "BUSY_POLL_S", "Child", "ChildFailed", "DemoConfig", "Pair", "Stack", "busy_poll_for",
           "cli_argv", "run_demo"]

GRACE_S = 5.0
BUSY_POLL_S = 0.002
"""How long the simulators' and agents' CAN-over-Zenoh buses keep polling after each sample
(``--busy-poll``; ``ZenohBus(busy_poll=...)``): longer than a lock-step cycle's answer takes,
so a polling thread is never woken during an episode (docs/performance.md)."""


def busy_poll_for(pairs: int, cores: int | None = None) -> float:
    """The polling window of ``pairs`` simulator/agent pairs by default: ``BUSY_POLL_S`` while
    the machine has a core for each polling bus (two a pair), else 0. Measured on 2 cores: one
    polling pair ran 1.4x the episodes of one sleeping pair, two polling pairs 0.85x of two
    sleeping ones (docs/performance.md)."""
    if cores is None:  # the processors this process may run on (a container's affinity), else all
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return BUSY_POLL_S if 2 * pairs <= cores else 0.0


_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


class ChildFailed(RuntimeError):
    """A child process exited early or did not become ready."""


class Child:
    """One child process in its own process group; output to a log file (and optionally echoed).

    The group stays in the demo's session (not ``setsid``): on Linux with autogroup scheduling
    every session is a scheduling group of its own, and a simulator and an agent in two groups
    handing every SYNC cycle to each other ran their episodes 15-20 % slower (docs/performance.md).

    Args:
        name: short name for messages and the log file.
        argv: the command.
        log_dir: where ``<name>.log`` goes.
        echo: called with every output line (e.g. print), or ``None``.
    """

    def __init__(self, name: str, argv: Sequence[str], log_dir: Path, env: dict[str, str],
                 echo: Callable[[str], None] | None = None) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_dir / f"{name}.log"
        self._echo = echo
        self._lines: list[str] = []
        self._cond = threading.Condition()
        self._log = open(self.log_path, "w", buffering=1)
        self._log.write("$ " + " ".join(self.argv) + "\n")
        self.proc = subprocess.Popen(
            self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, process_group=0, preexec_fn=_die_with_parent, text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read, name=f"{name}-output", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self._log.write(line + "\n")
            if self._echo is not None:
                self._echo(line)
            with self._cond:
                self._lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def lines(self) -> list[str]:
        """The output lines so far."""
        with self._cond:
            return list(self._lines)

    def wait_for(self, pattern: str, timeout_s: float, stop: threading.Event | None = None) -> re.Match:
        """Wait for an output line matching ``pattern``; raise ChildFailed on exit/timeout."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._cond:
            while True:
                for line in self._lines[seen:]:
                    match = regex.search(line)
                    if match:
                        return match
                seen = len(self._lines)
                if stop is not None and stop.is_set():
                    raise ChildFailed(f"{self.name}: interrupted")
                if not self.alive() and not self._reader.is_alive():
                    raise ChildFailed(f"{self.name} exited with {self.proc.returncode} before "
                                      f"printing /{pattern}/; see {self.log_path}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ChildFailed(f"{self.name} did not print /{pattern}/ within {timeout_s:g} s; "
                                      f"see {self.log_path}")
                self._cond.wait(min(left, 0.2))

    def stop(self, grace_s: float = GRACE_S) -> int | None:
        """SIGTERM the process group, SIGKILL it after ``grace_s``; returns the exit code."""
        if self.alive():
            self._signal(signal.SIGTERM)
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                self._log.write(f"[demo] {self.name} ignored SIGTERM for {grace_s:g} s: SIGKILL\n")
                self._signal(signal.SIGKILL)
                self.proc.wait(5.0)
        self._signal(signal.SIGKILL)  # stragglers left in the group
        self._reader.join(2.0)
        self._log.close()
        return self.proc.returncode

    def _signal(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


@dataclass(frozen=True)
class DemoConfig:
    """What ``ersac-hil demo`` runs.

    Attributes:
        task: ``bracing`` (default) or ``lifting``.
        kappa: risk sensitivity of the daemon.
        episodes: ok episodes to learn for.
        seed: run seed of the daemon and base seed of the simulator.
        out: report directory (holds the store ``demo.db`` and ``logs/``).
        robot: robot name.
        extra_daemon_args: appended to the daemon's command line.
        secure: TLS with client certificates and access control (certificates in OUT/certs).
        linger: keep the stack up after the report until stopped.
        router_host: loopback address the router listens on.
        daemon_host, agent_host: loopback source addresses of the daemon's and the agent's
            Zenoh links (``#bind=``), to put them on other addresses than the router.
        dashboard: also start ``ersac-hil dashboard`` and print its URL.
        dashboard_port: its port (0: a free one).
        can: CAN transport of the simulator/agent pair: ``direct``, ``zenoh`` or ``hub`` (see the
            module doc).
        fleet: simulator/agent pairs behind the daemon.
        batch: perturbations per update (``None``: ``fleet``).
    """

    task: str = "bracing"
    kappa: float = 2.0
    episodes: int = 45
    seed: int = 1
    out: Path = Path("demo-report")
    robot: str = "ubot1"
    extra_daemon_args: tuple[str, ...] = ()
    secure: bool = False
    linger: bool = False
    router_host: str = "127.0.0.1"
    daemon_host: str | None = None
    agent_host: str | None = None
    dashboard: bool = False
    dashboard_port: int = 8050
    can: str = "direct"
    fleet: int = 1
    batch: int | None = None
    busy_poll: float | None = None


def cli_argv(*args: str) -> list[str]:
    """``python -m ersac_hil.cli ARGS`` with this interpreter."""
    return [sys.executable, "-m", "ersac_hil.cli", *args]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    for key, value in (("OPENBLAS_NUM_THREADS", "1"), ("OMP_NUM_THREADS", "1"), ("MUJOCO_GL", "egl")):
        env.setdefault(key, value)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass(frozen=True)
class Pair:
    """One simulator/agent pair on its own CAN channel; its agent serves ``robot`` under
    the key prefix ``prefix`` (several pairs: one prefix each, so a run of robot ``robot``
    can go to any of them)."""

    robot: str
    prefix: str
    channel: str
    sim: Child
    agent: Child


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
    """

    def __init__(self, logs: Path, stop: threading.Event, say: Callable[[str], None] = print,
                 robot: str = "ubot1", seed: int = 1, pairs: int = 1, secure: bool = False,
                 router_host: str = "127.0.0.1", agent_host: str | None = None, can: str = "direct",
                 fleet: bool = False, busy_poll: float | None = None) -> None:
        from ersac_hil.zenoh_session import free_tcp_port

        self.logs, self.stop, self.say, self.robot = logs, stop, say, robot
        self.env = _env()
        self.children: list[Child] = []
        self.pairs: list[Pair] = []
        self.endpoint = f"{'tls' if secure else 'tcp'}/{router_host}:{free_tcp_port(router_host)}"
        self.roles: dict[str, str] = {}
        self._seed, self._n, self._secure, self._agent_host = seed, pairs, secure, agent_host
        self._fleet = fleet
        self._can = can
        self._busy_poll = busy_poll_for(pairs) if busy_poll is None else busy_poll
        logs.mkdir(parents=True, exist_ok=True)

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
            prefix = "ersac" if k == 1 or self._fleet else f"ersac{k}"
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
            sim = self.launch(f"sim{tag}", cli_argv("sim", *sim_bus, "--seed", str(self._seed + k - 1)))
            sims.append((tag, prefix, robot, channel, sim, agent_bus))
        for tag, prefix, robot, channel, sim, agent_bus in sims:
            if self._can == "direct":  # the agent's bus connects to the simulator's listener
                sim.wait_for(r"^simulator: \d+ nodes", 60, self.stop)
            agent = self.launch(f"agent{tag}", cli_argv("agent", "--robot", robot, "--prefix", prefix,
                                                        *agent_bus, *self.zenoh_args("agent", self._agent_host)))
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
        for child in watched:
            if not child.alive():
                raise ChildFailed(f"{child.name} exited with {child.proc.returncode}; see {child.log_path}")

    def close(self) -> None:
        """Stop every child, newest first; report unexpected exit codes."""
        for child in reversed(self.children):
            rc = child.stop()
            if rc not in (0, None, -signal.SIGTERM, 128 + signal.SIGTERM, 128 + signal.SIGINT):
                self.say(f"{child.name} exited with {rc} (log {child.log_path})")
        self.children = []

    def __enter__(self) -> Stack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_demo(config: DemoConfig, stop: threading.Event, say: Callable[[str], None] = print) -> int:
    """Run the demo until done or ``stop`` is set; always stops every child. Returns an exit code."""
    out = config.out.resolve()
    db = out / "demo.db"
    for stale in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
        stale.unlink(missing_ok=True)
    started = time.monotonic()
    stack = Stack(out / "logs", stop, lambda line: say(f"demo: {line}"), config.robot, config.seed,
                  pairs=config.fleet, secure=config.secure, router_host=config.router_host,
                  agent_host=config.agent_host, can=config.can, fleet=True, busy_poll=config.busy_poll)
    batch = config.fleet if config.batch is None else config.batch
    code = 1
    try:
        fleet = f", fleet of {config.fleet}, batch {batch}" if config.fleet > 1 or batch > 1 else ""
        say(f"demo: {config.task}, kappa {config.kappa:g}, {config.episodes} episodes, seed {config.seed}{fleet}"
            f"{', TLS + access control' if config.secure else ''}; logs in {stack.logs}")
        stack.start()
        endpoint, pair = stack.endpoint, stack.pairs[0]
        say(f"demo: router {endpoint}, CAN {', '.join(p.channel for p in stack.pairs)}")
        if config.dashboard:
            url = stack.launch("dashboard", cli_argv(
                "dashboard", "--robot", config.robot, *stack.zenoh_args("operator"),
                "--port", str(config.dashboard_port))).wait_for(r"^dashboard: (http://\S+)", 30, stop)
            say(f"demo: dashboard {url.group(1)}")
        daemon = stack.launch("daemon", cli_argv(
            "daemon", *[a for p in stack.pairs for a in ("--robot", p.robot)], "--batch", str(batch),
            "--task", config.task, "--kappa", repr(config.kappa),
            "--episodes", str(config.episodes), "--seed", str(config.seed),
            *stack.zenoh_args("daemon", config.daemon_host), "--db", str(db), "--new", "--agent-wait", "120",
            *(["--linger"] if config.linger else []), *config.extra_daemon_args),
            echo=lambda line: say(f"  {line}"))
        info = {"secure": config.secure, "router": endpoint, "robot": config.robot, "prefix": pair.prefix,
                "can": pair.channel, "fleet": [{"robot": p.robot, "can": p.channel} for p in stack.pairs], "db": str(db), "ca": str(out / "certs" / "ca.crt") if stack.roles else None,
                "configs": stack.roles, "pids": {c.name: c.pid for c in stack.children}}
        (out / "stack.json").write_text(json.dumps(info, indent=2) + "\n")
        say("demo: children " + " ".join(f"{c.name}={c.pid}" for c in stack.children))
        finished = re.compile(r"run \S+ (finished|failed)")
        while daemon.alive() and not stop.is_set() and not (
                config.linger and any(finished.search(line) for line in daemon.lines())):
            stack.check()
            time.sleep(0.2)
        if stop.is_set():
            say("demo: interrupted, stopping everything")
            code = 130
            return code
        if config.linger and daemon.alive():
            code = 0
        else:
            code = daemon.proc.wait()
            daemon.stop()
        if code != 0:
            say(f"demo: the daemon exited with {code}; see {daemon.log_path}")
        from ersac_hil.daemon.report import write_report
        from ersac_hil.daemon.store import Store
        with Store(db, readonly=True) as store:
            runs = store.runs()
            attempts = store.attempts(runs[-1].run_id) if runs else []
        if not runs:
            say("demo: no run in the store, no report")
            return code or 1
        summary = write_report(db, runs[-1].run_id, out)
        cost = summary["cost"]
        last = cost["last_10"]
        ends = [a.finished_s for a in attempts if a.finished_s is not None]
        learning = (f" (learning {max(ends) - min(a.requested_s for a in attempts):.1f} s: first request "
                    "to last result)") if ends else ""
        say(f"demo: {summary['episodes']} episodes in {time.monotonic() - started:.0f} s{learning}; final theta "
            f"{[round(t, 4) for t in summary['final_theta']]}; cost mean {cost['all']['mean']:.3f}"
            + (f", last 10 mean {last['mean']:.3f} +/- {last['std']:.3f}" if last["n"] else ""))
        say(f"demo: report in {out} ({', '.join(summary['files'])})")
        if config.linger:
            say(f"demo: stack up on {endpoint} (see {out / 'stack.json'}); Ctrl-C stops it")
            while not stop.wait(0.5):
                stack.check(stack.children)
            say("demo: stopping the stack")
        return code
    except ChildFailed as exc:
        say(f"demo: {exc}")
        return 130 if stop.is_set() else 1
    finally:
        stack.close()


def _demo(args: argparse.Namespace) -> int:
    from ersac_hil.lifecycle import until_signal
    config = DemoConfig(args.task, args.kappa, args.episodes, args.seed, Path(args.out), args.robot,
                        secure=args.secure, linger=args.linger, dashboard=args.dashboard,
                        dashboard_port=args.dashboard_port, can=args.can, fleet=args.fleet, batch=args.batch,
                        busy_poll=args.busy_poll)
    return until_signal(lambda stop: run_demo(config, stop, lambda line: print(line, flush=True)))


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``ersac-hil`` parser."""
    p = sub.add_parser("demo", help="router, simulator, agent and learner on loopback; a report")
    p.add_argument("--task", choices=("bracing", "lifting"), default="bracing")
    p.add_argument("--kappa", type=finite_float, default=2.0, help="risk sensitivity (default 2)")
    p.add_argument("--episodes", type=positive_int, default=45, help="episodes to learn for (default 45)")
    p.add_argument("--seed", type=non_negative_int, default=1, help="run and simulator seed (default 1)")
    p.add_argument("--out", type=output_dir, default="demo-report",
                   help="report directory (default ./demo-report)")
    p.add_argument("--robot", default="ubot1", help="robot name (default ubot1)")
    p.add_argument("--secure", action="store_true",
                   help="TLS with client certificates and access control by role (certs in OUT/certs)")
    p.add_argument("--dashboard", action="store_true", help="also serve the live dashboard; prints its URL")
    p.add_argument("--dashboard-port", dest="dashboard_port", type=tcp_port, default=8050,
                   help="dashboard port (default 8050; 0 = a free one)")
    p.add_argument("--can", choices=("direct", "zenoh", "hub"), default="direct",
                   help="CAN between simulator and agent: over Zenoh on a direct link, the agent "
                        "connected to the simulator (default; with --secure TLS and the router's "
                        "access control on the simulator's listener), over Zenoh through the "
                        "router, or on a python-can-remote loopback hub")
    p.add_argument("--fleet", type=positive_int, default=1, metavar="N",
                   help="simulator/agent pairs behind the one daemon (default 1)")
    p.add_argument("--batch", type=positive_int, metavar="K",
                   help="perturbations per update, run in parallel on the fleet (default: N; 1 = the paper's)")
    p.add_argument("--busy-poll", dest="busy_poll", type=non_negative_float, metavar="S",
                   help=f"CAN over Zenoh: the simulators' and agents' buses poll S seconds after each frame "
                        f"instead of sleeping (0 = off; default {BUSY_POLL_S} where the machine has a core "
                        f"for each polling bus, two per pair, else 0)")
    p.add_argument("--linger", action="store_true",
                   help="keep the stack up after the report until Ctrl-C (attach with OUT/stack.json)")
    p.set_defaults(func=_demo, validate=_validate)


def _validate(args: argparse.Namespace) -> None:
    """What the daemon child would refuse (robot name, kappa range...), refused before any child."""
    from ersac_hil.daemon.config import ConfigError, DaemonConfig
    try:
        DaemonConfig(robot=args.robot, task=args.task, kappa=args.kappa, episodes=args.episodes,
                     seed=args.seed, batch=args.fleet if args.batch is None else args.batch,
                     fleet=tuple(f"{args.robot}-{k}" for k in range(2, args.fleet + 1)))
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
