"""``ersac-hil demo``: the whole stack on loopback, one learning run, a report, clean shutdown.

Child processes, each in its own process group, started in this order and stopped in the
reverse order (SIGTERM, then SIGKILL after a grace period; also on Ctrl-C/SIGTERM of the demo,
and the kernel kills them if the demo itself dies, via PR_SET_PDEATHSIG; a second Ctrl-C kills
them at once)::

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
``OUT/stack.json`` says where the router is, which config each role uses and the children's pids
while the stack runs (``"stopped": true`` and no pids once it has stopped), so a person or a
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
import json
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ersac_hil.cli_args import (UsageError, finite_float, non_negative_float, non_negative_int, output_dir,
                                positive_int, tcp_port)
from ersac_hil.daemon.config import task_defaults
from ersac_hil.stack import BUSY_POLL_S, PAIRS_PER_CORE, ChildFailed, Stack, TooManyPairs, check_pairs, cli_argv
from protocol.robot import default_description
from protocol.robot.cli import add_description_argument

__all__ = ["register", "DemoConfig", "run_demo"]

PAPER_EPISODES = task_defaults("bracing").episodes
"""The demo's learning budget: the paper's bracing run (whatever ``--task``)."""


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
        description: the robot description of the simulators and agents (a shipped name or a
            file; ``None``: the default, ``ubot5``).
        ros2: the agents publish for ROS 2 (``agent --ros2``, docs/ros2.md) and record each
            episode as ``OUT/mcap/<episode_id>.mcap``.
    """

    task: str = "bracing"
    kappa: float = 2.0
    episodes: int = PAPER_EPISODES
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
    ros2: bool = False
    description: str | None = None


def run_demo(config: DemoConfig, stop: threading.Event, say: Callable[[str], None] = print) -> int:
    """Run the demo until done or ``stop`` is set; always stops every child. Returns an exit code."""
    out = config.out.resolve()
    db = out / "demo.db"
    for stale in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
        stale.unlink(missing_ok=True)
    for stale in (out / "series").glob("*.npz"):  # a previous demo's episodes
        stale.unlink()
    started = time.monotonic()
    stack = Stack(out / "logs", stop, lambda line: say(f"demo: {line}"), config.robot, config.seed,
                  pairs=config.fleet, secure=config.secure, router_host=config.router_host,
                  agent_host=config.agent_host, can=config.can, fleet=True, busy_poll=config.busy_poll,
                  series=out / "series", description=config.description,
                  agent_args=("--ros2", "--record", str(out / "mcap")) if config.ros2 else ())
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
        summary = write_report(db, runs[-1].run_id, out, series=out / "series")
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
        if (out / "stack.json").is_file():  # the stack is gone: no pids left to attach to or signal
            info = json.loads((out / "stack.json").read_text())
            (out / "stack.json").write_text(json.dumps({**info, "stopped": True, "pids": {}}, indent=2) + "\n")


def _demo(args: argparse.Namespace) -> int:
    from ersac_hil.lifecycle import until_signal
    config = DemoConfig(args.task, args.kappa, args.episodes, args.seed, Path(args.out), args.robot,
                        secure=args.secure, linger=args.linger, dashboard=args.dashboard,
                        dashboard_port=args.dashboard_port, can=args.can, fleet=args.fleet, batch=args.batch,
                        busy_poll=args.busy_poll, ros2=args.ros2,
                        description=None if args.description is default_description() else args.description.source)
    return until_signal(lambda stop: run_demo(config, stop, lambda line: print(line, flush=True)))


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``ersac-hil`` parser."""
    p = sub.add_parser("demo", help="router, simulator, agent and learner on loopback; a report")
    p.add_argument("--task", choices=("bracing", "lifting"), default="bracing")
    p.add_argument("--kappa", type=finite_float, default=2.0, help="risk sensitivity (default 2)")
    p.add_argument("--episodes", type=positive_int, default=PAPER_EPISODES,
                   help=f"episodes to learn for (default {PAPER_EPISODES}, the paper's bracing run)")
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
                   help=f"simulator/agent pairs behind the one daemon (default 1; at most {PAIRS_PER_CORE} "
                        "a core this process may use unless --oversubscribe)")
    p.add_argument("--oversubscribe", action="store_true",
                   help=f"start --fleet N even above {PAIRS_PER_CORE} pairs a core this process may use")
    p.add_argument("--batch", type=positive_int, metavar="K",
                   help="perturbations per update, run in parallel on the fleet (default: N; 1 = the paper's)")
    p.add_argument("--busy-poll", dest="busy_poll", type=non_negative_float, metavar="S",
                   help=f"CAN over Zenoh: the simulators' and agents' buses poll S seconds after each frame "
                        f"instead of sleeping (0 = off; default {BUSY_POLL_S} where the machine has a core "
                        f"for each polling bus, two per pair, else 0)")
    p.add_argument("--ros2", action="store_true",
                   help="the agent publishes for ROS 2 (rmw_zenoh key space, domain 0, /<robot>) and "
                        "records each episode as OUT/mcap/<episode_id>.mcap (docs/ros2.md)")
    p.add_argument("--linger", action="store_true",
                   help="keep the stack up after the report until Ctrl-C (attach with OUT/stack.json)")
    add_description_argument(p, drives=True)
    p.set_defaults(func=_demo, validate=_validate)


def _validate(args: argparse.Namespace) -> None:
    """What the daemon child would refuse (robot name, kappa range...) and a fleet larger than
    the cores this process may use run, refused before any child."""
    from ersac_hil.daemon.config import ConfigError, DaemonConfig
    if not args.oversubscribe:
        try:
            check_pairs(args.fleet, "--fleet", "--oversubscribe")
        except TooManyPairs as exc:
            raise UsageError(str(exc)) from None
    try:
        DaemonConfig(robot=args.robot, task=args.task, kappa=args.kappa, episodes=args.episodes,
                     seed=args.seed, batch=args.fleet if args.batch is None else args.batch,
                     fleet=tuple(f"{args.robot}-{k}" for k in range(2, args.fleet + 1)))
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
