"""The bracing trade-off through the real pipeline: simulator -> CANopen -> agent -> cost terms.

    .venv/bin/python bench/bracing_sweep.py [--seeds 8] [--first-seed 0] [--thetas 0,0.1,...,1]
                                           [--episodes]

For every theta of the grid, runs one bracing episode per seed (first-seed .. first-seed +
seeds - 1, the same seeds for every theta: common random numbers, so differences between
thetas are not seed noise) on an
in-process simulated bench over a virtual CAN bus, exactly as the learner would get them
(``EpisodeRunner.plan`` / ``run``, the agent's default configuration and weights). Prints per
theta: the arm stiffness, mean and standard deviation of the total cost J, the damage rate
(elbow cable broken), the fall rate, and the mean of every cost term; then the argmin over the
grid of mean J + kappa * std J for kappa in {0, 1, 2} (kappa = 0: the risk-neutral optimum).

No pass/fail: figures only. One episode takes ~0.4-1 s of wall time; the default grid (11 x 8)
takes 1-2 minutes on one core. OPENBLAS_NUM_THREADS=1 (2-core machine).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import uuid
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ersac_hil.agent.bus import AgentBus  # noqa: E402
from ersac_hil.agent.episode import EpisodeConfig, EpisodeRunner  # noqa: E402
from firmware_sim.nodes.simbench import SimulatedBench  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.zenoh import TASKS, EpisodeRequest, EpisodeResult  # noqa: E402

KAPPAS = (0.0, 1.0, 2.0)


def sweep(thetas: list[float], seeds: int, first_seed: int = 0) -> dict[float, list[EpisodeResult]]:
    """{theta: [result per seed]} for seeds first_seed .. first_seed + seeds - 1; every result
    has status ok (else RuntimeError)."""
    config = BusConfig("virtual", f"sweep-{uuid.uuid4().hex[:8]}")
    out: dict[float, list[EpisodeResult]] = {}
    with SimulatedBench(config):
        bus = AgentBus(config).open()
        try:
            bus.wait_for_nodes()
            runner = EpisodeRunner(bus)
            for theta in thetas:
                out[theta] = []
                for seed in range(first_seed, first_seed + seeds):
                    req = EpisodeRequest(f"sw-{uuid.uuid4().hex[:8]}", "bracing", (theta,), seed)
                    r = runner.run(runner.plan(req))
                    if r.status != "ok":
                        raise RuntimeError(f"theta {theta} seed {seed}: {r.status} {r.detail}")
                    out[theta].append(r)
        finally:
            bus.close()
    return out


def table(results: dict[float, list[EpisodeResult]]) -> list[tuple[float, float, float]]:
    """Print the table; returns (theta, mean J, std J) per theta."""
    policy = EpisodeConfig().task("bracing").policy  # the agent's default theta -> stiffness map
    terms = TASKS["bracing"].term_names
    head = (f"{'theta':>5} {'K':>6} {'mean J':>7} {'std J':>6} {'damage':>6} {'fallen':>6} "
            + " ".join(f"{t:>11}" for t in terms))
    print(head)
    rows = []
    for theta, rs in results.items():
        costs = [r.total_cost for r in rs]
        mean, std = statistics.fmean(costs), statistics.stdev(costs) if len(costs) > 1 else 0.0
        dmg = statistics.fmean(r.failed("hardware_damage") for r in rs)
        fall = statistics.fmean(r.failed("fallen") for r in rs)
        means = [statistics.fmean(r.cost_terms[t] for r in rs) for t in terms]
        print(f"{theta:5.2f} {policy.stiffness(theta):6.1f} {mean:7.1f} {std:6.1f} "
              f"{dmg:6.2f} {fall:6.2f} " + " ".join(f"{m:11.2f}" for m in means))
        rows.append((theta, mean, std))
    return rows


def episodes(results: dict[float, list[EpisodeResult]]) -> None:
    """One line per episode: theta, seed, impact momentum (bench ground truth), J, terms."""
    for theta, rs in results.items():
        for r in rs:
            p = r.telemetry.get("bench_impact_momentum_ns", float("nan"))
            terms = " ".join(f"{k} {v:8.2f}" for k, v in r.cost_terms.items())
            print(f"theta {theta:4.2f} p {p:5.2f} J {r.total_cost:7.1f} {terms} "
                  f"fallen {int(r.failed('fallen'))}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8, help="episodes per theta")
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first .. first + seeds - 1")
    ap.add_argument("--thetas", default=",".join(f"{0.1 * i:.1f}" for i in range(11)),
                    help="comma-separated theta grid in [0, 1]")
    ap.add_argument("--episodes", action="store_true", help="also print every episode")
    args = ap.parse_args()
    thetas = [float(t) for t in args.thetas.split(",")]
    t0 = time.perf_counter()
    results = sweep(thetas, args.seeds, args.first_seed)
    wall = time.perf_counter() - t0
    weights = TASKS["bracing"].default_weights
    print(f"bracing sweep: {len(thetas)} thetas x {args.seeds} seeds through the virtual-bus stack, "
          f"J = " + " + ".join(f"{w:g} {n}" for n, w in weights.items()))
    if args.episodes:
        episodes(results)
    rows = table(results)
    for kappa in KAPPAS:
        theta, mean, std = min(rows, key=lambda r: r[1] + kappa * r[2])
        print(f"argmin mean J + {kappa:g} std J: theta {theta:.2f} "
              f"(mean {mean:.1f}, std {std:.1f}, F {mean + kappa * std:.1f})")
    n = len(thetas) * args.seeds
    print(f"{n} episodes in {wall:.0f} s ({wall / n:.2f} s per episode)")


if __name__ == "__main__":
    main()
