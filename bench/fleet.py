"""Throughput of independent episodes on a fleet of N simulator/agent pairs behind one client.

    python bench/fleet.py [--fleet 1,2] [--busy-poll auto,0] [--episodes 16] [--rounds 2] [--task bracing]
                          [--out DIR] [--agents KEYEXPR --zenoh-config FILE]

For each N the stack of ``ersac-hil demo --fleet N`` is started (embedded router, N simulator
and N agent processes, each pair on its own CAN-over-Zenoh channel); the same M independent
episodes (fixed theta, scenario seeds 0..M-1) go through ``ersac_hil.daemon.fleet.Fleet`` (the
daemon's dispatcher: each request to whichever agent is free). After one warm-up episode per
agent, the wall time from the first request to the last result gives episodes per second,
the aggregate real-time factor (simulated seconds per wall second) and the speed-up over N = 1.
``--busy-poll`` gives the CAN buses' polling window(s) in seconds (``Stack(busy_poll=...)``;
default ``auto``, the demo's choice for each N, ``ersac_hil.stack.busy_poll_for``; several,
comma-separated, are compared). The sizes (and windows) are interleaved round by round (1,
2, 1, 2, ...) so every comparison is from the same run; the load average is printed beside
every figure (a shared 2-core machine).

``--agents KEYEXPR`` (with ``--zenoh``/``--zenoh-config``) measures the pairs already running
elsewhere behind a router instead (``ersac_hil.stack.remote``, docs/reproduce.md "On a fleet"):
one size, the agents found; nothing is started.

It also checks that the results do not depend on the fleet: every episode's cost terms must be
bit-identical for every N and round (the scenario seed travels in the request).

No pass/fail: figures only (goal of issue 12: x1.6 for N = 2 on 2 cores). With ``--out`` a bar
chart ``fleet.png`` is written.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ersac_hil.daemon.discovery import NoAgents, reach_agents  # noqa: E402
from ersac_hil.daemon.fleet import Fleet  # noqa: E402
from ersac_hil.stack import Stack, busy_poll_for  # noqa: E402
from ersac_hil.stack.remote import Agents, RemoteAgents, add_agents_arguments, agents_from_args  # noqa: E402
from ersac_hil.zenoh_session import open_session, resolve_config  # noqa: E402
from protocol.zenoh import EpisodeRequest, get_task  # noqa: E402

THETA = {"bracing": (0.5,), "lifting": (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2)}


def load() -> str:
    return " ".join(f"{v:.1f}" for v in os.getloadavg())


def run_fleet(n: int, task: str, m: int, logs: Path, tag: str, busy_poll: float | None = None,
              agents: tuple[Agents, list[str]] | None = None) -> tuple[float, dict[int, dict]]:
    """Start the stack with ``n`` pairs (or use ``agents``: the ``n`` robots found behind their
    router), run ``m`` episodes; (wall seconds, seed -> cost terms)."""
    stop = threading.Event()
    where = logs / f"{tag}-n{n}-p{busy_poll}"
    with (RemoteAgents(where, stop, lambda _line: None, agents[1], agents[0].prefix, agents[0].options) if agents
          else Stack(where, stop, lambda _line: None, pairs=n, fleet=True, busy_poll=busy_poll)) as stack:
        stack.start()
        options = stack.zenoh_options()
        session = open_session(resolve_config(options), insecure=options.insecure)
        fleet = Fleet(session, stack.pairs[0].prefix, [p.robot for p in stack.pairs], 300.0, stop)
        try:
            deadline = time.monotonic() + 120
            while len(fleet.ready()) < n:
                stack.check()
                if time.monotonic() > deadline:
                    raise RuntimeError(f"only {fleet.ready()} of {n} agents ready after 120 s")
                time.sleep(0.05)

            def batch(seeds, label: str) -> dict[int, dict]:
                for s in seeds:
                    fleet.submit(EpisodeRequest(f"{label}.{s:05d}.0", task, THETA[task], s))
                out = {}
                while len(out) < len(seeds):
                    done = fleet.outcome(1.0)
                    if done is None:
                        stack.check()
                        continue
                    if done.outcome.status != "ok":
                        raise RuntimeError(f"{done.request.episode_id}: {done.outcome.status} {done.outcome.detail}")
                    out[done.request.seed] = dict(done.outcome.result.cost_terms)
                return out

            batch(range(10_000, 10_000 + n), "warmup")  # one per agent, not timed
            t0 = time.monotonic()
            results = batch(range(m), "bench")
            return time.monotonic() - t0, results
        finally:
            stop.set()
            fleet.close()
            session.close()


def _window(n: int, poll: float | None) -> str:
    return f"{busy_poll_for(n):g} s (auto)" if poll is None else f"{poll:g} s"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fleet", default="1,2", help="fleet sizes, comma-separated (default 1,2)")
    ap.add_argument("--episodes", type=int, default=16, help="timed episodes per size and round")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (default 2)")
    ap.add_argument("--task", choices=sorted(THETA), default="bracing")
    ap.add_argument("--out", type=Path, help="write fleet.png here")
    ap.add_argument("--busy-poll", dest="busy_poll", default="auto",
                    help="CAN buses' polling window(s) in s, comma-separated (0 = off; default auto: the demo's)")
    add_agents_arguments(ap)
    args = ap.parse_args()
    agents, refusal = agents_from_args(args)
    if refusal:
        print(f"fleet: {refusal}", file=sys.stderr)
        return 2
    sizes = [int(x) for x in args.fleet.split(",")]
    polls = [None if x == "auto" else float(x) for x in args.busy_poll.split(",")]
    found = None
    if agents is not None:
        try:
            found = agents, reach_agents(agents.options, agents.source, agents.prefix, agents.wait_s,
                                         threading.Event())
        except NoAgents as exc:
            print(f"fleet: --agents {agents.source}: {exc}", file=sys.stderr)
            return 2
        sizes, polls = [len(found[1])], [None]
        print(f"agents behind the router: {', '.join(found[1])} (their own busy polling)")
    variants = [(n, p) for n in sizes for p in polls]
    horizon = get_task(args.task).horizon_s
    print(f"{args.task}: {args.episodes} independent episodes per fleet size, sizes {sizes}, busy polling "
          f"{args.busy_poll}, {args.rounds} interleaved rounds; {os.cpu_count()} cores; load average {load()}",
          flush=True)
    walls: dict[tuple[int, float | None], list[float]] = {v: [] for v in variants}
    reference: dict[int, dict] | None = None
    identical = True
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        for r in range(args.rounds):
            for n, poll in variants:
                before = load()
                wall, results = run_fleet(n, args.task, args.episodes, Path(tmp), f"r{r}", poll, found)
                walls[n, poll].append(wall)
                if reference is None:
                    reference = results
                identical &= results == reference
                print(f"round {r + 1} N={n} busy_poll {_window(n, poll)}: {args.episodes} episodes in "
                      f"{wall:6.2f} s = "
                      f"{args.episodes / wall:5.2f} episodes/s, RTF {args.episodes * horizon / wall:5.2f}x "
                      f"(load {before} -> {load()})", flush=True)
    print(f"\n| N | busy poll | episodes/s (median of {args.rounds}) | aggregate RTF | speed-up vs N={sizes[0]} |")
    print("|---|---|---|---|---|")
    rows = []
    for n, poll in variants:
        base = statistics.median(walls[sizes[0], poll])
        wall = statistics.median(walls[n, poll])
        label = f"{n}" if len(polls) == 1 else f"{n}, {_window(n, poll)}"
        rows.append((label, args.episodes / wall, base / wall))
        print(f"| {n} | {_window(n, poll)} | {args.episodes / wall:.2f} | {args.episodes * horizon / wall:.2f}x | "
              f"x{base / wall:.2f} |")
    print(f"\nresults identical for every fleet size, window and round: {'yes' if identical else 'NO'}; "
          f"load average at the end {load()}")
    if args.out is not None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        args.out.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(5 + len(rows) // 3, 3.5), constrained_layout=True)
        ax.bar([label for label, _, _ in rows], [e for _, e, _ in rows], color="tab:blue")
        for i, (_, e, x) in enumerate(rows):
            ax.text(i, e, f"x{x:.2f}", ha="center", va="bottom")
        ax.set_xlabel("simulator/agent pairs N" + ("" if len(polls) == 1 else ", busy polling"))
        ax.set_ylabel(f"{args.task} episodes / s")
        ax.set_title(f"independent episodes on a fleet ({os.cpu_count()} cores, load {load()})", fontsize=9)
        fig.savefig(args.out / "fleet.png", dpi=110)
        print(f"wrote {args.out / 'fleet.png'}")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
