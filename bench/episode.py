"""Episode speed through the whole stack: Zenoh query -> agent -> CANopen -> simulator.

    python bench/episode.py [--episodes N] [--realtime] [--drives ubot-board|cia402|cia402-cst]
    python bench/episode.py --realtime --only direct --drives cia402-cst --minutes 10

Per available CAN backend, runs N bracing (theta 0.5) and N lifting (a sensible spline)
episodes by ``episode/run`` queries from a Zenoh client through an embedded router, and prints
the median wall time, the real-time factor (simulated episode time / wall time) and the
SYNC-cycle latency (SYNC sent -> last TPDO of that SYNC received) p50/p99 as the agent measured
it; in real time also each SYNC's jitter against its slot on the absolute schedule and the
host's compute time per cycle (a cycle's TPDOs to the next SYNC, pacing excluded) p50/p99/max,
and the missed periods. Drive profiles (both processes get the description): ``--drives
ubot-board`` (the uBot boards, ``ubot5``, the default), ``cia402`` (``ubot5-cia402``: wheels in
CST with the host's LQR, arms and torso in CSP with the drives' impedance), ``cia402-cst``
(the same robot with every axis in CST: the impedance law on the host every SYNC, the host
torque loop), or ``--description NAME|PATH``. ``--minutes M`` runs bracing and lifting
episodes in turn for M minutes instead of N each (the endurance figure: p99 is the worst
episode's, an upper bound of the p99 over all cycles). Backends:

* ``virtual``: agent and simulated robot in this process (python-can's virtual bus is
  in-process only);
* ``remote``: the loopback hub in this process, the simulator (``python -m firmware_sim``) and
  the agent (``ersac-hil agent``) as separate processes, as deployed;
* ``zenoh``: CAN over Zenoh (``ersac_hil.canbus.zenoh_bus``) through the same embedded router
  the episode queries use, simulator and agent as separate processes;
* ``direct``: CAN over Zenoh on a direct link (``ersac_hil.canbus.direct``, what ``ersac-hil
  demo`` uses): the simulator's bus listens on a free loopback port, the agent's connects to it;
* ``ipc``: CAN over a Unix socket (``ersac_hil.canbus.ipc``): the simulator's bus listens on a
  socket in a temporary directory, the agent's connects to it;
* ``socketcan`` on vcan0, same processes as ``remote``, where the kernel has SocketCAN.

On ``zenoh`` and ``direct`` both buses busy-poll in lock-step as ``ersac-hil demo``'s do
(``--busy-poll S``, default the demo's for one pair on this machine,
``ersac_hil.stack.busy_poll_for``; 0 = off); not in real time by default (a sample every 5 ms
outlasts the window: nothing gained, docs/performance.md).

No pass/fail: figures only. OPENBLAS_NUM_THREADS=1 (2-core machine).

Side by side with another checkout (an older main, its own venv or this one)::

    python bench/episode.py --baseline ../old-main [--baseline-bus remote] [--rounds 3] [--only zenoh]

``--agent-args "..."`` adds flags to this checkout's agents only, so ``--baseline .`` with
``--agent-args "--ros2 --record DIR"`` (and ``--busy-poll 0``, as the baseline side) measures
the ROS 2 bridge and MCAP recording against the same stack without them; repeated, each set
runs in every round after the baseline (``--agent-args=--ros2 --agent-args "--ros2 --record
DIR"``: off, bridge, bridge and recording, interleaved). Without ``--baseline`` each set runs
in turn on every process backend of ``--only`` (``--realtime --agent-args=--keep-awake``).
``--baseline-agent-args "..."`` gives the baseline's agents flags of their own (a real-time
comparison with ``--keep-awake`` on both sides).

runs the process backends of ``--only`` round by round, the other checkout's simulator and
agent first (never busy-polling: ``--baseline .`` compares polling with not), then this one's
(``--baseline-bus remote``: the other side over the loopback hub, for a main without CAN over
Zenoh), prints both rows per round with the load average, and
checks that both gave the same cost terms and telemetry for every episode (same seed, same
policy: bit-identical; lock-step only, real-time episodes follow the wall clock).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ersac_hil.canbus import LoopbackHub, vcan_status  # noqa: E402
from ersac_hil.stack import busy_poll_for  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter, free_tcp_port  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.zenoh import EpisodeRequest, EpisodeResult, ErrorReply, KeySpace  # noqa: E402

ROBOT = "bench"
KS = KeySpace(ROBOT)
TASKS = {"bracing": (0.5,), "lifting": (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2)}


def wait_for_agent(session, timeout_s: float = 10.0) -> None:
    """Until the agent's liveliness token is visible (its queryable is declared before it):
    declarations reach a new client asynchronously, and a get before that has no replies."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if any(r.ok is not None for r in session.liveliness().get(KS.agent_alive, timeout=1)):
            return
        time.sleep(0.05)
    raise RuntimeError(f"no agent at {KS.agent_alive} within {timeout_s} s")


def run_episode(session, task: str, seed: int) -> EpisodeResult:
    req = EpisodeRequest(f"bench-{uuid.uuid4().hex[:8]}", task, TASKS[task], seed)
    (reply,) = list(session.get(KS.episode_run, payload=req.to_json(), timeout=120))
    if reply.ok is None:
        raise RuntimeError(ErrorReply.from_json(reply.err.payload.to_bytes()).reason)
    return EpisodeResult.from_json(reply.ok.payload)


def run_episodes(session, n: int, minutes: float | None = None) -> dict[str, list[EpisodeResult]]:
    """``n`` episodes of each task, or (``minutes``) both tasks in turn until that long passed."""
    wait_for_agent(session)
    out: dict[str, list[EpisodeResult]] = {task: [] for task in TASKS}
    if minutes is None:
        for task in TASKS:
            out[task] = [run_episode(session, task, seed) for seed in range(n)]
        return out
    end, seed = time.monotonic() + 60.0 * minutes, 0
    while time.monotonic() < end:
        for task in TASKS:
            out[task].append(run_episode(session, task, seed))
        seed += 1
    return out


DRIVES = {"ubot-board": "ubot5", "cia402": "ubot5-cia402", "cia402-cst": "ubot5-cia402"}
"""``--drives``: the shipped description of each profile (``cia402-cst``: every axis in CST)."""


def description_for(drives: str, workdir: Path) -> str:
    """The ``--description`` both processes get for ``--drives``: a shipped name, or for
    ``cia402-cst`` a copy of ``ubot5-cia402`` with its impedance axes in CST in ``workdir``."""
    name = DRIVES[drives]
    if drives != "cia402-cst":
        return name
    from protocol.robot.load import SHIPPED_DIR
    text = (SHIPPED_DIR / f"{name}.toml").read_text()
    path = workdir / f"{name}-cst.toml"
    path.write_text(text.replace('name = "ubot5-cia402"', 'name = "ubot5-cia402-cst"')
                        .replace('mode = "csp-impedance"', 'mode = "cst"'))
    return str(path)


def in_process(config: BusConfig, n: int, realtime: bool, description: str | None = None,
               minutes: float | None = None) -> dict[str, list[EpisodeResult]]:
    from ersac_hil.agent.bus import BusTiming
    from ersac_hil.agent.service import AgentConfig, AgentService
    from firmware_sim.nodes.simrobot import SimulatedRobot
    from protocol.robot import load_description

    robot = load_description(description or "ubot5")
    with EmbeddedRouter() as router, SimulatedRobot(config, realtime=realtime, description=robot):
        agent = AgentConfig(robot=ROBOT, bus=config, zenoh_connect=(router.endpoint,),
                            timing=BusTiming(realtime=realtime), description=robot)
        with AgentService(agent), router.open_client() as session:
            return run_episodes(session, n, minutes)


def _ready(proc: subprocess.Popen, marker: str) -> str:
    """Read ``proc``'s output up to its ready line; return the scheduling line before it."""
    said = ""
    while True:
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"{proc.args[:3]} exited before '{marker}'")
        if "SCHED_FIFO" in line or "scheduling" in line:
            said = line.strip()
        if marker in line and "SCHED_FIFO" not in line:
            return said


DIRECT = "direct"
"""``processes``' config for CAN over Zenoh on a direct link (the simulator listens)."""
IPC = "ipc"
"""``processes``' config for CAN over a Unix socket (the simulator listens)."""


def processes(config: BusConfig | str | None, n: int, realtime: bool,
              checkout: Path | None = None, python: str = sys.executable,
              busy_poll: float = 0.0, agent_args: tuple[str, ...] = (), description: str | None = None,
              minutes: float | None = None) -> dict[str, list[EpisodeResult]]:
    """Simulator and agent as processes on ``config`` (``None``: CAN over Zenoh on the router;
    ``DIRECT``: CAN over Zenoh, the agent's bus connected to the simulator's; ``IPC``: the same
    on a Unix socket), run by ``python``
    from ``checkout`` (default: this one); ``busy_poll``: both CAN-over-Zenoh buses' (s, 0: off);
    ``description``: both processes' robot description (default theirs, the boards')."""
    extra = ["--realtime"] if realtime else []
    if description is not None:
        extra += ["--description", description]
    polling = [f"busy_poll={busy_poll}"] if busy_poll else []
    procs = []
    try:
        with EmbeddedRouter() as router, tempfile.TemporaryDirectory(prefix="bench-ipc-") as sockets:
            sim_bus = None
            if config == IPC:
                path = str(Path(sockets) / "can.sock")
                sim_bus = ["--bus-interface", "ipc", "--bus-channel", path, "--bus-kwargs", "listen=true"]
                config = BusConfig("ipc", path)
            elif config == DIRECT:
                name, listen = f"bench-{uuid.uuid4().hex[:6]}", f"tcp/127.0.0.1:{free_tcp_port()}"
                sim_bus = ["--bus-interface", "zenoh", "--bus-channel", name, "--bus-kwargs", f"listen={listen}",
                           *polling]
                config = BusConfig("zenoh", f"{name}@{listen}")
            elif config is None:
                config = BusConfig("zenoh", f"bench-{uuid.uuid4().hex[:6]}@{router.endpoint}")
            bus_args = ["--bus-interface", config.interface, "--bus-channel", config.channel]
            if config.interface == "zenoh" and polling:
                bus_args += ["--bus-kwargs", *polling]
            sim = subprocess.Popen([python, "-m", "firmware_sim", *(sim_bus or bus_args), *extra],
                                   stdout=subprocess.PIPE, text=True, cwd=checkout)
            procs.append(sim)
            scheduling = [_ready(sim, "simulator: ")]
            agent = subprocess.Popen([python, "-m", "ersac_hil.cli", "agent", "--robot", ROBOT,
                                      *bus_args, "--zenoh", router.endpoint, *extra, *agent_args],
                                     stdout=subprocess.PIPE, text=True, cwd=checkout)
            procs.append(agent)
            scheduling.append(_ready(agent, "agent ready"))
            if realtime:
                print("  " + "; ".join(line for line in scheduling if line))
            with router.open_client() as session:
                before = cpu_seconds(sim.pid, agent.pid)
                results = run_episodes(session, n, minutes)
                after = cpu_seconds(sim.pid, agent.pid)
                print("  CPU s of the episodes of the row below: " + "  ".join(
                    f"{name} {after[name] - before.get(name, 0.0):.2f}" for name in after))
                return results
    finally:
        for p in procs:
            p.terminate()
            p.communicate(timeout=10)


_TICK = os.sysconf("SC_CLK_TCK")


def _proc_cpu(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (all its threads), 0 when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / _TICK


def _children(pid: int) -> list[int]:
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return []
    return [int(c) for t in tasks for c in (t / "children").read_text().split()]


def cpu_seconds(sim: int, agent: int) -> dict[str, float]:
    """CPU seconds so far of the simulator, the agent, the agent's children (the ROS 2 feed
    process) and this process (the embedded router and the client): where a variant's cost goes."""
    return {"simulator": _proc_cpu(sim), "agent": _proc_cpu(agent),
            "agent's children": sum(_proc_cpu(c) for c in _children(agent)),
            "router+client": sum(os.times()[:2])}


def report(backend: str, results: dict[str, list[EpisodeResult]]) -> None:
    for task, rs in results.items():
        ok = [r for r in rs if r.status == "ok"]
        wall = statistics.median(r.wall_s for r in rs)
        sim = statistics.median(r.duration_s for r in rs)
        p50 = statistics.median(r.telemetry.get("sync_latency_p50_ms", float("nan")) for r in rs)
        p99 = max(r.telemetry.get("sync_latency_p99_ms", float("nan")) for r in rs)
        worst = max(r.telemetry.get("sync_latency_max_ms", float("nan")) for r in rs)
        cycles = statistics.median(r.telemetry.get("n_cycles", 0.0) for r in rs)
        missed = sum(r.fault_counts.get("late_cycles", 0) for r in rs)
        total = sum(r.telemetry.get("n_cycles", 0.0) for r in rs)
        print(f"{backend:<10} {task:<8} {len(ok)}/{len(rs)} ok  sim {sim:5.2f} s  wall {wall:5.2f} s  "
              f"RTF {sim / wall:5.2f}  {cycles / wall:6.0f} cycles/s  "
              f"SYNC latency p50 {p50:5.2f} ms  p99 {p99:6.2f} ms  max {worst:6.2f} ms  "
              f"missed periods {missed}/{total:.0f}")
        if "sync_jitter_p99_ms" in rs[0].telemetry:  # real time
            print(f"{'':<10} {task:<8} SYNC latency p99 median {_median(rs, 'sync_latency_p99_ms'):5.2f} ms  "
                  f"jitter p50/p99/max {_median(rs, 'sync_jitter_p50_ms'):5.3f}/{_worst(rs, 'sync_jitter_p99_ms'):5.3f}/"
                  f"{_worst(rs, 'sync_jitter_max_ms'):5.3f} ms  host compute p50/p99/max "
                  f"{_median(rs, 'host_compute_p50_ms'):5.3f}/{_worst(rs, 'host_compute_p99_ms'):5.3f}/"
                  f"{_worst(rs, 'host_compute_max_ms'):5.3f} ms  ({len(rs)} episodes)")


def _median(rs: list[EpisodeResult], key: str) -> float:
    return statistics.median(r.telemetry.get(key, float("nan")) for r in rs)


def _worst(rs: list[EpisodeResult], key: str) -> float:
    return max(r.telemetry.get(key, float("nan")) for r in rs)


def _measured(r: EpisodeResult) -> tuple:
    """What an episode measured (not how fast): identical for the same seed and policy."""
    timing = {f"{name}_{q}_ms" for name in ("sync_latency", "sync_jitter", "host_compute") for q in ("p50", "p99", "max")}
    return (r.status, sorted(r.cost_terms.items()), r.total_cost, sorted(r.failures.items()),
            sorted((k, v) for k, v in r.telemetry.items() if k not in timing))


def _on(bus: str, run):  # noqa: ANN001, ANN202
    """``run(config)`` on ``bus`` ("zenoh": ``None``, the router's channel; "remote": a hub)."""
    if bus == "remote":
        with LoopbackHub() as hub:
            return run(hub.bus_config)
    return run(bus if bus in (DIRECT, IPC) else None)


def compare(args: argparse.Namespace) -> int:
    """Rounds of the other checkout, then this one; rows per round; identical episodes?"""
    other = args.baseline.resolve()
    python = args.baseline_python or (str(other / ".venv/bin/python") if (other / ".venv/bin/python").exists()
                                      else sys.executable)
    if os.sep in python:  # a path: it runs from the other checkout
        python = str(Path(python).absolute())
    here = Path(__file__).resolve().parents[1]
    robot = None if args.robot == "ubot5" else args.robot  # an older checkout may not know --description
    same = True
    for rnd in range(1, args.rounds + 1):
        base = _on(args.baseline_bus, lambda c: processes(c, args.episodes, args.realtime, other, python,
                                                          agent_args=args.baseline_agent_args, description=robot))
        print(f"round {rnd}  load average {os.getloadavg()[0]:.2f}")
        report(f"base-{args.baseline_bus}", base)
        for backend in args.only or ("zenoh",):
            if backend == "virtual":
                continue
            for variant in args.agent_args or [()]:  # each after the baseline, in the same round
                new = _on(backend, lambda c: processes(c, args.episodes, args.realtime, here,
                                                       busy_poll=args.busy_poll, agent_args=variant,
                                                       description=robot))
                report(backend + "".join(f" {a}" for a in variant), new)
                if args.realtime:  # the physics follows the wall clock: episodes differ by design
                    continue
                for task in new:
                    for a, b in zip(base[task], new[task]):
                        if _measured(a) != _measured(b):
                            same = False
                            print(f"  DIFFERENT {task} episode: {a.cost_terms} vs {b.cost_terms}")
    verdict = ("not compared (real time: the physics follows the wall clock)" if args.realtime
               else "yes" if same else "NO")
    print(f"load average {os.getloadavg()[0]:.2f}; baseline {other} ({python}); "
          f"every episode identical to the baseline's: {verdict}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=3, help="episodes per task and backend")
    parser.add_argument("--realtime", action="store_true", help="real-time mode (agent and simulator)")
    parser.add_argument("--only", action="append", choices=("virtual", "remote", "zenoh", DIRECT, IPC),
                        help="only these backends (repeatable; default all)")
    parser.add_argument("--baseline", type=Path, help="another checkout to run side by side")
    parser.add_argument("--baseline-python", help="its Python (default its .venv, else this one)")
    parser.add_argument("--baseline-bus", choices=("zenoh", "remote", DIRECT, IPC), default="zenoh")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of baseline then this checkout")
    parser.add_argument("--busy-poll", dest="busy_poll", type=float, metavar="S",
                        help="CAN over Zenoh: this checkout's buses poll S seconds after each sample "
                             f"(default {busy_poll_for(1):g} in lock-step, the demo's for one pair here; "
                             "0 in real time, where it gained nothing; 0 = off)")
    parser.add_argument("--agent-args", dest="agent_args", type=lambda t: tuple(t.split()), action="append",
                        help="further flags of this checkout's agents, e.g. \"--ros2 --record DIR\"; repeatable: "
                             "each set is run after the baseline in every round (\"\" for none); without --baseline, each set in turn")
    parser.add_argument("--baseline-agent-args", dest="baseline_agent_args", type=lambda t: tuple(t.split()),
                        default=(), help="further flags of the baseline's agents (e.g. --keep-awake, for a real-time "
                                         "comparison with --agent-args=--keep-awake)")
    robot = parser.add_mutually_exclusive_group()
    robot.add_argument("--drives", choices=tuple(DRIVES), default="ubot-board",
                       help="drive profile of simulator and agent (default ubot-board; cia402-cst: every "
                            "axis in CST, the impedance law on the host)")
    robot.add_argument("--description", metavar="NAME|PATH", help="robot description of both processes")
    parser.add_argument("--minutes", type=float, metavar="M",
                        help="both tasks in turn for M minutes instead of --episodes each")
    args = parser.parse_args()
    if args.minutes is not None and (args.minutes <= 0 or args.baseline is not None):
        parser.error("--minutes must be positive and is not for --baseline")
    if args.description is not None:
        from protocol.robot import DescriptionError, load_description
        try:
            load_description(args.description)
        except (DescriptionError, OSError) as exc:
            parser.error(f"--description: {exc}")
    with tempfile.TemporaryDirectory(prefix="bench-episode-") as tmp:
        args.robot = args.description or description_for(args.drives, Path(tmp))
        return _main(args)


def _main(args: argparse.Namespace) -> int:
    if args.busy_poll is None:
        args.busy_poll = 0.0 if args.realtime else busy_poll_for(1)
    mode = "real-time" if args.realtime else "lock-step"
    print(f"load average {os.getloadavg()[0]:.2f} (2-core machine shared with other jobs)")
    amount = f"{args.minutes:g} minutes" if args.minutes else f"{args.episodes} per task"
    print(f"episodes through Zenoh -> agent -> CAN -> simulator ({mode}, {amount}, robot {args.robot}; "
          f"median wall, worst p99 over the episodes; OPENBLAS_NUM_THREADS=1)")
    if args.baseline is not None:
        return compare(args)
    only = args.only or ("virtual", "remote", "zenoh", DIRECT, IPC)
    robot = {"description": args.robot, "minutes": args.minutes}
    if "virtual" in only:
        if args.agent_args:  # the in-process run has no agent process to take them
            print("virtual    skipped: --agent-args are flags of an agent process")
        else:
            report("virtual", in_process(BusConfig("virtual", f"bench-{uuid.uuid4().hex[:6]}"),
                                         args.episodes, args.realtime, **robot))
    for variant in args.agent_args or [()]:  # each set of agent flags in turn
        label = "".join(f" {a}" for a in variant)
        if "remote" in only:
            with LoopbackHub() as hub:
                report("remote" + label, processes(hub.bus_config, args.episodes, args.realtime,
                                                   agent_args=variant, **robot))
        if "zenoh" in only:
            report("zenoh" + label, processes(None, args.episodes, args.realtime, busy_poll=args.busy_poll,
                                              agent_args=variant, **robot))
        if DIRECT in only:
            report(DIRECT + label, processes(DIRECT, args.episodes, args.realtime, busy_poll=args.busy_poll,
                                             agent_args=variant, **robot))
        if IPC in only:
            report(IPC + label, processes(IPC, args.episodes, args.realtime, agent_args=variant, **robot))
    print(f"load average {os.getloadavg()[0]:.2f}")
    if args.only:
        return 0
    status = vcan_status("vcan0")
    if status.available:
        report("socketcan", processes(BusConfig("socketcan", "vcan0"), args.episodes, args.realtime, **robot))
    else:
        print(f"socketcan  skipped: {status.reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
