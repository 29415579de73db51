"""The lifting cost landscape along the time scale of a policy, on real physics, in-process.

    .venv/bin/python bench/lifting_landscape.py [--scales 0.6,0.8,...] [--trials 10]
                                                [--theta0 7 values] [--out DIR]

Each point is the start policy (default: the daemon's lifting ``theta0``) with its three
segment durations multiplied by a scale (clipped into the task bounds), run on ``--trials``
scenario seeds (605000.., the block ``reproduce`` tests lifting with; the same seeds at every
point: common random numbers) through the agent's episode runner on a simulated robot over a
virtual CAN bus. Per point: mean and std of the total cost (the task's default weights), the
success rate (the bottle held and at the goal height at the end, as ``reproduce`` counts it),
the rate of dropped bottles, and the mean final height of the failures that kept the bottle
(stalls). Small scales are fast, violent lifts (drops); large ones slow lifts that the
torque-limited shoulders stall (docs/robot_model.md). With ``--out DIR``:
``lifting_landscape.json`` and ``lifting_landscape.png``. No pass/fail.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import uuid
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from ersac_hil.agent.bus import AgentBus  # noqa: E402
from ersac_hil.agent.episode import EpisodeRunner  # noqa: E402
from ersac_hil.daemon.config import TASK_DEFAULTS  # noqa: E402
from firmware_sim.nodes.simrobot import SimulatedRobot  # noqa: E402
from lifting_learning import TEST_SEED, lifted, run_episode, theta_arg  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.zenoh import get_task  # noqa: E402


def scaled(theta0: np.ndarray, scale: float) -> np.ndarray:
    """``theta0`` (7,) with its three durations times ``scale``, inside the task bounds."""
    spec = get_task("lifting")
    theta = np.array(theta0, dtype=float)
    theta[4:] = np.clip(theta[4:] * scale, np.array(spec.lower)[4:], np.array(spec.upper)[4:])
    return theta


def point(runner: EpisodeRunner, bus: AgentBus, theta: np.ndarray, trials: int) -> dict[str, object]:
    """Cost (trials,), success, drop rate and stall height of ``theta`` on the test seeds."""
    spec = get_task("lifting")
    weights = dict(spec.default_weights)
    results = [run_episode(runner, bus, theta, TEST_SEED + t) for t in range(trials)]
    costs = np.array([spec.total_cost(r.cost_terms, weights) for r in results])
    ok = np.array([lifted(r) for r in results])
    dropped = np.array([bool(r.failures.get("bottle_dropped")) for r in results])
    stalls = [r.telemetry["final_bottle_height_m"] for r, s, d in zip(results, ok, dropped) if not s and not d]
    return {"theta": theta.tolist(), "costs": costs.tolist(), "success": float(ok.mean()),
            "dropped": float(dropped.mean()), "stall_height_m": float(np.mean(stalls)) if stalls else None}


def _plot(points: list[dict[str, object]], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    s = np.array([p["scale"] for p in points])
    c = [np.array(p["costs"]) for p in points]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    ax.errorbar(s, [v.mean() for v in c], [v.std() for v in c], fmt="o-", capsize=3)
    for x, v in zip(s, c):
        ax.plot(np.full(len(v), x), v, ".", color="grey", alpha=0.5)
    ax.set_ylabel("total cost (mean +- std, trials)")
    ax.set_title("lifting: cost along the time scale of the start policy")
    ax2.plot(s, [p["success"] for p in points], "o-", label="success")
    ax2.plot(s, [p["dropped"] for p in points], "s--", label="dropped")
    ax2.set_xlabel("scale of the three segment durations")
    ax2.set_ylabel("rate")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scales", type=lambda t: theta_arg(t).tolist(),
                   default=[0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.2, 1.4, 1.7, 2.0])
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--theta0", type=theta_arg, default=np.array(TASK_DEFAULTS["lifting"].theta0))
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    if args.trials < 1 or args.theta0.shape != (7,) or min(args.scales) <= 0:
        p.error("--trials >= 1, --theta0 7 values, --scales > 0")
    points: list[dict[str, object]] = []
    start = time.monotonic()
    config = BusConfig("virtual", f"lifting-landscape-{uuid.uuid4().hex[:8]}")
    print("| scale | durations (s) | mean cost | std | success | dropped | stall height (m) |\n"
          "|---|---|---|---|---|---|---|", flush=True)
    with SimulatedRobot(config):
        bus = AgentBus(config).open()
        try:
            bus.wait_for_nodes()
            runner = EpisodeRunner(bus)
            for scale in args.scales:
                pt = {"scale": scale, **point(runner, bus, scaled(args.theta0, scale), args.trials)}
                points.append(pt)
                c = np.array(pt["costs"])
                stall = "-" if pt["stall_height_m"] is None else f"{pt['stall_height_m']:.2f}"
                durations = ", ".join(f"{v:.2f}" for v in pt["theta"][4:])
                print(f"| {scale:.2f} | {durations} | {c.mean():.2f} | {c.std():.2f} | {pt['success']:.0%} | "
                      f"{pt['dropped']:.0%} | {stall} |", flush=True)
        finally:
            bus.close()
    print(f"({len(points) * args.trials} episodes, {time.monotonic() - start:.0f} s, "
          f"load {os.getloadavg()[0]:.1f})")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "lifting_landscape.json").write_text(json.dumps(points, indent=1))
        _plot(points, args.out / "lifting_landscape.png")
        print(f"written: {args.out}/lifting_landscape.json, lifting_landscape.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
