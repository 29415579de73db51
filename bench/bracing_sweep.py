"""The bracing landscape through the real pipeline: simulator -> CANopen -> agent -> cost terms.

    .venv/bin/python bench/bracing_sweep.py [--episodes 30] [--first-seed 0] [--step 0.05]
                                           [--thetas 0,0.5,1] [--bootstrap 1000]
                                           [--out DIR] [--per-episode] [--drives cia402]
                                           [--pairs N | --agents KEYEXPR --zenoh-config FILE]

For every theta of the grid (default 0, 0.05, ..., 1), runs ``--episodes`` bracing episodes,
seeds first-seed .. first-seed + episodes - 1 (the same seeds for every theta: common random
numbers, so differences between thetas are not seed noise), on an in-process simulated robot
over a virtual CAN bus, exactly as the learner gets them (``EpisodeRunner.plan`` / ``run``, the
agent's default configuration and weights; ``--drives cia402``: the same robot on CiA 402
drives, ``ubot5-cia402``, through the agent's CiA 402 profile). Prints one progress line per theta, then the table
(theta, K, mean, std and F2 = mean + 2 std of the total cost J with bootstrap standard errors,
damage and fall rates, the mean of every cost term), the argmin over the grid of
mean + kappa std for kappa 0, 1, 2, and the F2 gap between the kappa-0 and kappa-2 optima with
its bootstrap standard error. The bootstrap resamples seeds (paired across thetas).

Where the episodes run: by default in this process; ``--pairs N`` on N simulator/agent pairs
started here (router, simulators and agents as processes, the stack of ``ersac-hil demo --fleet
N``); ``--agents KEYEXPR`` (with ``--zenoh``/``--zenoh-config``) on the pairs already running
elsewhere behind a router, e.g. ``--agents 'ubot$*'`` (docs/reproduce.md, "On a fleet"). The
last two are one code path (``sweep_pairs``: each request through the daemon's dispatcher to
whichever agent is free, the scenario seed in the request), and all three give the same
episodes bit for bit.

With ``--out DIR``: ``landscape.md`` (the table), ``landscape.json`` (everything, every
episode's terms) and ``landscape.png`` (mean, mean +- 2 std band, damage rate).

An episode that ends in a bus fault (e.g. a board that lost the agent's heartbeat while the
machine was starved) is run again and listed (count, theta, seed, load average): it is not a
measurement of the landscape.

No pass/fail: figures only. One episode takes ~0.3-1 s of wall time. OPENBLAS_NUM_THREADS=1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from ersac_hil.agent.bus import AgentBus  # noqa: E402
from ersac_hil.agent.cia402 import agent_bus  # noqa: E402
from ersac_hil.agent.episode import EpisodeRunner  # noqa: E402
from ersac_hil.agent.policies import BracingPolicy  # noqa: E402
from ersac_hil.daemon.discovery import NoAgents, reach_agents  # noqa: E402
from ersac_hil.daemon.fleet import Fleet  # noqa: E402
from ersac_hil.reproduce.runner import EPISODE_TIMEOUT_S  # noqa: E402
from ersac_hil.stack import Stack  # noqa: E402
from ersac_hil.stack.remote import RemoteAgents, add_agents_arguments, agents_from_args  # noqa: E402
from ersac_hil.zenoh_session import open_session, resolve_config  # noqa: E402
from firmware_sim.nodes.simrobot import SimulatedRobot  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from ersac_hil.reproduce import figures  # noqa: E402
from ersac_hil.reproduce.stats import Landscape  # noqa: E402
from protocol.robot import RobotDescription, default_description, load_description  # noqa: E402
from protocol.zenoh import TASKS, EpisodeRequest, EpisodeResult  # noqa: E402

DRIVES = {"ubot-board": "ubot5", "cia402": "ubot5-cia402"}
"""``--drives``: the shipped description of the uBot on each drive profile."""

KAPPAS = (0.0, 1.0, 2.0)
TERMS = TASKS["bracing"].term_names


@dataclass(frozen=True)
class Rerun:
    """An episode that ended in a bus fault (not a task outcome) and was run again."""
    theta: float
    seed: int
    status: str
    detail: str
    load: float


def settle(bus: AgentBus, quiet_s: float = 1.0, deadline_s: float = 30.0) -> None:
    """After a bus fault: wait until every node is back and no EMCY has come for ``quiet_s``
    (each board reports a lost heartbeat on its own timer; a late one would otherwise land in
    the next episode and fail it too), at most ``deadline_s``."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        n = bus.emcy_count
        time.sleep(quiet_s)
        if bus.emcy_count == n:
            break
    bus.wait_for_nodes()


def sweep(thetas: list[float], episodes: int, first_seed: int = 0, retries: int = 5,
          progress=print, reruns: list[Rerun] | None = None,
          description: RobotDescription | None = None) -> dict[float, list[EpisodeResult]]:
    """{theta: [result per seed]}; every result has status ok. An episode that ends in a bus
    fault (``fault_*``: e.g. a board that lost the agent's heartbeat on a starved machine) is
    recorded in ``reruns`` and run again, up to ``retries`` times (the episode is deterministic
    for its seed, so the rerun is the episode that should have run); then RuntimeError."""
    config = BusConfig("virtual", f"sweep-{uuid.uuid4().hex[:8]}")
    out: dict[float, list[EpisodeResult]] = {}
    reruns = [] if reruns is None else reruns
    t0 = time.perf_counter()
    description = description or default_description()
    with SimulatedRobot(config, description=description):
        bus = agent_bus(config, description).open()
        try:
            bus.wait_for_nodes()
            runner = EpisodeRunner(bus)
            for i, theta in enumerate(thetas):
                out[theta] = []
                for seed in range(first_seed, first_seed + episodes):
                    for attempt in range(retries + 1):
                        req = EpisodeRequest(f"sw-{uuid.uuid4().hex[:8]}", "bracing", (theta,), seed)
                        r = runner.run(runner.plan(req))
                        if r.status == "ok" or not r.status.startswith("fault_") or attempt == retries:
                            break
                        _rerun(reruns, theta, seed, r.status, r.detail, progress)
                        settle(bus)
                    if r.status != "ok":
                        raise RuntimeError(f"theta {theta} seed {seed}: {r.status} {r.detail}")
                    out[theta].append(r)
                progress(_theta_line(i, len(thetas), theta, out[theta], t0))
        finally:
            bus.close()
    return out


def _rerun(reruns: list[Rerun], theta: float, seed: int, status: str, detail: str, progress) -> None:  # noqa: ANN001
    reruns.append(Rerun(theta, seed, status, detail, os.getloadavg()[0]))
    progress(f"  theta {theta:.2f} seed {seed}: {status} ({detail}), load {os.getloadavg()[0]:.1f}: run again")


def _theta_line(i: int, n: int, theta: float, results: list[EpisodeResult], t0: float) -> str:
    costs = [r.total_cost for r in results]
    return (f"[{i + 1}/{n}] theta {theta:.2f}: mean J {np.mean(costs):7.1f} std {np.std(costs, ddof=1):6.1f} "
            f"damage {np.mean([r.failed('hardware_damage') for r in results]):.2f} ({time.perf_counter() - t0:.0f} s)")


#: Outcomes of a request on a fleet that are not the episode's (a bus fault, an agent gone, no
#: reply in time): the request is sent again, to any agent.
_RETRIED = ("lost", "timeout")


def sweep_fleet(thetas: list[float], episodes: int, fleet: Fleet, first_seed: int = 0, retries: int = 5,
                progress=print, reruns: list[Rerun] | None = None,  # noqa: ANN001
                check=lambda: None) -> dict[float, list[EpisodeResult]]:  # noqa: ANN001
    """:func:`sweep` on simulator/agent pairs: every (theta, seed) is an ``EpisodeRequest`` queued
    on ``fleet`` (``ersac_hil.daemon.fleet.Fleet``, the daemon's dispatcher: each to whichever
    agent is free), the scenario seed in the request, so the results are the same whichever agent
    ran what. A bus fault, a lost agent or a timeout is recorded in ``reruns`` and sent again,
    up to ``retries`` times; anything else, or more, RuntimeError. ``check()`` runs while
    waiting (e.g. ``Stack.check``: a pair that died)."""
    results: dict[float, list[EpisodeResult | None]] = {theta: [None] * episodes for theta in thetas}
    attempts: dict[tuple[float, int], int] = {}
    reruns = [] if reruns is None else reruns
    t0 = time.perf_counter()

    def submit(theta: float, seed: int) -> None:
        fleet.submit(EpisodeRequest(f"sw-{uuid.uuid4().hex[:8]}", "bracing", (theta,), seed))

    for theta in thetas:
        for seed in range(first_seed, first_seed + episodes):
            submit(theta, seed)
    left = len(thetas) * episodes
    while left:
        done = fleet.outcome(1.0)
        if done is None:
            check()
            continue
        theta, seed = done.request.theta[0], done.request.seed
        status, detail = (done.outcome.status, done.outcome.detail) if done.outcome else ("error", str(done.error))
        if status == "ok":
            results[theta][seed - first_seed] = done.outcome.result
            left -= 1
            if all(r is not None for r in results[theta]):
                progress(_theta_line(thetas.index(theta), len(thetas), theta, results[theta], t0) + f" on {done.robot}")
            continue
        tries = attempts[theta, seed] = attempts.get((theta, seed), 0) + 1
        if not (status.startswith("fault_") or status in _RETRIED) or tries > retries:
            raise RuntimeError(f"theta {theta} seed {seed} on {done.robot}: {status} {detail}")
        _rerun(reruns, theta, seed, status, detail, progress)
        submit(theta, seed)
    return results  # type: ignore[return-value]


def sweep_pairs(thetas: list[float], episodes: int, stack: Stack, first_seed: int = 0, progress=print,  # noqa: ANN001
                reruns: list[Rerun] | None = None) -> dict[float, list[EpisodeResult]]:
    """:func:`sweep_fleet` on the pairs of ``stack``: a ``Stack`` started here (``--pairs``) or
    ``RemoteAgents`` running behind a router (``--agents``), the same way for both; closes it."""
    stop = threading.Event()
    try:
        stack.start()
        options = stack.zenoh_options()
        session = open_session(resolve_config(options), insecure=options.insecure)
        try:
            fleet = Fleet(session, stack.pairs[0].prefix, [p.robot for p in stack.pairs], EPISODE_TIMEOUT_S, stop)
            try:
                return sweep_fleet(thetas, episodes, fleet, first_seed, progress=progress, reruns=reruns,
                                   check=stack.check)
            finally:
                stop.set()
                fleet.close()
        finally:
            session.close()
    finally:
        stack.close()


def landscape(results: dict[float, list[EpisodeResult]], n_boot: int, seed: int = 0) -> Landscape:
    """The shared landscape statistics (``ersac_hil.reproduce.stats.Landscape``) of a sweep."""
    thetas = sorted(results)
    rows = [results[t] for t in thetas]
    policy = BracingPolicy()
    return Landscape.from_arrays(
        thetas, [[r.total_cost for r in row] for row in rows],
        [[r.failed("hardware_damage") for r in row] for row in rows],
        [[r.failed("fallen") for r in row] for row in rows], TERMS,
        [[[r.cost_terms[k] for k in TERMS] for r in row] for row in rows],
        [policy.stiffness(t) for t in thetas], n_boot, seed)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=30, help="episodes (seeds) per theta")
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first .. first + episodes - 1")
    ap.add_argument("--step", type=float, default=0.05, help="theta grid step over [0, 1]")
    ap.add_argument("--thetas", default=None, help="comma-separated theta grid (overrides --step)")
    ap.add_argument("--bootstrap", type=int, default=1000, help="bootstrap replicates")
    ap.add_argument("--out", type=Path, default=None, help="directory for landscape.{md,json,png}")
    ap.add_argument("--per-episode", action="store_true", help="also print every episode")
    ap.add_argument("--drives", choices=sorted(DRIVES), default="ubot-board",
                    help="drive profile of the simulated uBot (default: its own boards; with --agents: whatever "
                    "the agents were started with)")
    ap.add_argument("--pairs", type=int, default=None,
                    help="run the episodes on N simulator/agent pairs started here (the processes of ersac-hil "
                    "demo --fleet N) through the daemon's dispatcher instead of in this process")
    add_agents_arguments(ap)
    args = ap.parse_args()
    if args.episodes < 2 or not 0 < args.step <= 1:
        ap.error("--episodes must be >= 2 and --step in (0, 1]")
    agents, refusal = agents_from_args(args)
    if refusal or (args.pairs is not None and args.pairs < 1):
        print(f"bracing_sweep: {refusal or '--pairs must be >= 1'}", file=sys.stderr)
        return 2
    thetas = ([float(t) for t in args.thetas.split(",")] if args.thetas
              else [round(x, 6) for x in np.arange(0.0, 1.0 + 1e-9, args.step)])
    stack, where = None, f"{args.drives}, in-process on a virtual bus"
    with tempfile.TemporaryDirectory(prefix="bracing-sweep-") as tmp:
        logs = (args.out / "logs") if args.out is not None else Path(tmp)
        if agents is not None:
            try:
                robots = reach_agents(agents.options, agents.source, agents.prefix, agents.wait_s, threading.Event())
            except NoAgents as exc:
                print(f"bracing_sweep: --agents {agents.source}: {exc}", file=sys.stderr)
                return 2
            stack = RemoteAgents(logs, threading.Event(), print, robots, agents.prefix, agents.options)
            where = f"on {len(robots)} agent(s) behind the router: {', '.join(robots)}"
        elif args.pairs is not None:
            stack = Stack(logs, threading.Event(), print, pairs=args.pairs, fleet=True, description=DRIVES[args.drives])
            where = f"{args.drives}, on {args.pairs} simulator/agent pair(s) started here"
        t0 = time.perf_counter()
        reruns: list[Rerun] = []
        results = (sweep(thetas, args.episodes, args.first_seed, reruns=reruns,
                         description=load_description(DRIVES[args.drives])) if stack is None
                   else sweep_pairs(thetas, args.episodes, stack, args.first_seed, reruns=reruns))
        wall = time.perf_counter() - t0
    weights = TASKS["bracing"].default_weights
    print(f"bracing landscape ({where}): {len(thetas)} thetas x {args.episodes} seeds, J = "
          + " + ".join(f"{w:g} {n}" for n, w in weights.items()))
    if args.per_episode:
        for theta, rs in results.items():
            for r in rs:
                p = r.telemetry.get("truth_impact_momentum_ns", float("nan"))
                print(f"theta {theta:4.2f} p {p:5.2f} J {r.total_cost:7.1f} "
                      + " ".join(f"{k} {v:8.2f}" for k, v in r.cost_terms.items()))
    land = landscape(results, args.bootstrap)
    print(land.markdown())
    n = len(thetas) * args.episodes
    print(f"{n} episodes in {wall:.0f} s ({wall / n:.2f} s per episode, load average "
          f"{os.getloadavg()[0]:.1f}); {len(reruns)} episode(s) ended in a bus fault and ran again"
          + "".join(f"\n  theta {x.theta:.2f} seed {x.seed}: {x.status} at load {x.load:.1f}" for x in reruns))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "landscape.md").write_text(land.markdown() + "\n")
        g, se = land.gap(2.0)
        doc = {"episodes": args.episodes, "first_seed": args.first_seed, "weights": dict(weights),
               "rows": land.rows(),
               "argmin": {f"{k:g}": float(land.thetas[land.argmin(k)]) for k in KAPPAS},
               "F2_gap": g, "F2_gap_se": se, "wall_s": wall,
               "reruns": [{"theta": x.theta, "seed": x.seed, "status": x.status, "detail": x.detail,
                           "load": x.load} for x in reruns],
               "episodes_detail": {f"{t:.2f}": [{"seed": args.first_seed + i, "total_cost": r.total_cost,
                                                  "terms": dict(r.cost_terms),
                                                  "momentum": r.telemetry.get("truth_impact_momentum_ns")}
                                                 for i, r in enumerate(rs)]
                                   for t, rs in results.items()}}
        (args.out / "landscape.json").write_text(json.dumps(doc, indent=1))
        figures.landscape(land, args.out / "landscape.png")
        print(f"wrote {args.out}/landscape.md, landscape.json, landscape.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
