"""The bracing landscape through the real pipeline: simulator -> CANopen -> agent -> cost terms.

    .venv/bin/python bench/bracing_sweep.py [--episodes 30] [--first-seed 0] [--step 0.05]
                                           [--thetas 0,0.5,1] [--bootstrap 1000]
                                           [--out DIR] [--per-episode]

For every theta of the grid (default 0, 0.05, ..., 1), runs ``--episodes`` bracing episodes,
seeds first-seed .. first-seed + episodes - 1 (the same seeds for every theta: common random
numbers, so differences between thetas are not seed noise), on an in-process simulated bench
over a virtual CAN bus, exactly as the learner gets them (``EpisodeRunner.plan`` / ``run``, the
agent's default configuration and weights). Prints one progress line per theta, then the table
(theta, K, mean, std and F2 = mean + 2 std of the total cost J with bootstrap standard errors,
damage and fall rates, the mean of every cost term), the argmin over the grid of
mean + kappa std for kappa 0, 1, 2, and the F2 gap between the kappa-0 and kappa-2 optima with
its bootstrap standard error. The bootstrap resamples seeds (paired across thetas).

With ``--out DIR``: ``landscape.md`` (the table), ``landscape.json`` (everything, every
episode's terms) and ``landscape.png`` (mean, mean +- 2 std band, damage rate).

No pass/fail: figures only. One episode takes ~0.3-1 s of wall time. OPENBLAS_NUM_THREADS=1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from ersac_hil.agent.bus import AgentBus  # noqa: E402
from ersac_hil.agent.episode import EpisodeRunner  # noqa: E402
from ersac_hil.agent.policies import BracingPolicy  # noqa: E402
from firmware_sim.nodes.simbench import SimulatedBench  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.zenoh import TASKS, EpisodeRequest, EpisodeResult  # noqa: E402

KAPPAS = (0.0, 1.0, 2.0)
TERMS = TASKS["bracing"].term_names


def sweep(thetas: list[float], episodes: int, first_seed: int = 0,
          progress=print) -> dict[float, list[EpisodeResult]]:
    """{theta: [result per seed]}; every result has status ok (else RuntimeError)."""
    config = BusConfig("virtual", f"sweep-{uuid.uuid4().hex[:8]}")
    out: dict[float, list[EpisodeResult]] = {}
    t0 = time.perf_counter()
    with SimulatedBench(config):
        bus = AgentBus(config).open()
        try:
            bus.wait_for_nodes()
            runner = EpisodeRunner(bus)
            for i, theta in enumerate(thetas):
                out[theta] = []
                for seed in range(first_seed, first_seed + episodes):
                    req = EpisodeRequest(f"sw-{uuid.uuid4().hex[:8]}", "bracing", (theta,), seed)
                    r = runner.run(runner.plan(req))
                    if r.status != "ok":
                        raise RuntimeError(f"theta {theta} seed {seed}: {r.status} {r.detail}")
                    out[theta].append(r)
                costs = [r.total_cost for r in out[theta]]
                progress(f"[{i + 1}/{len(thetas)}] theta {theta:.2f}: mean J {np.mean(costs):7.1f} "
                         f"std {np.std(costs, ddof=1):6.1f} damage "
                         f"{np.mean([r.failed('hardware_damage') for r in out[theta]]):.2f} "
                         f"({time.perf_counter() - t0:.0f} s)")
        finally:
            bus.close()
    return out


@dataclass(frozen=True)
class Landscape:
    """Per theta (shape (m,) arrays): the cost matrix J (m, n seeds), damage/fall flags (m, n),
    term means (m, len(TERMS)), and the paired-bootstrap replicates of mean and std (B, m)."""
    thetas: np.ndarray
    stiffness: np.ndarray
    J: np.ndarray
    damage: np.ndarray
    fallen: np.ndarray
    terms: np.ndarray
    boot_mean: np.ndarray
    boot_std: np.ndarray

    @classmethod
    def from_results(cls, results: dict[float, list[EpisodeResult]], n_boot: int,
                     seed: int = 0) -> "Landscape":
        thetas = np.array(sorted(results))
        rs = [results[t] for t in thetas]
        J = np.array([[r.total_cost for r in row] for row in rs])
        idx = np.random.default_rng(seed).integers(0, J.shape[1], size=(n_boot, J.shape[1]))
        samples = J[:, idx]                                    # (m, B, n): seeds resampled jointly
        policy = BracingPolicy()
        return cls(thetas, np.array([policy.stiffness(t) for t in thetas]), J,
                   np.array([[r.failed("hardware_damage") for r in row] for row in rs], float),
                   np.array([[r.failed("fallen") for r in row] for row in rs], float),
                   np.array([[np.mean([r.cost_terms[k] for r in row]) for k in TERMS] for row in rs]),
                   samples.mean(axis=2).T, samples.std(axis=2, ddof=1).T)

    @property
    def mean(self) -> np.ndarray:
        return self.J.mean(axis=1)

    @property
    def std(self) -> np.ndarray:
        return self.J.std(axis=1, ddof=1)

    def objective(self, kappa: float) -> np.ndarray:
        return self.mean + kappa * self.std

    def argmin(self, kappa: float) -> int:
        return int(np.argmin(self.objective(kappa)))

    def se(self, kappa: float) -> np.ndarray:
        """Bootstrap standard error of mean + kappa std, shape (m,)."""
        return (self.boot_mean + kappa * self.boot_std).std(axis=0, ddof=1)

    def gap(self, kappa: float = 2.0) -> tuple[float, float]:
        """F_kappa at the kappa-0 optimum minus F_kappa at the kappa optimum, and the bootstrap
        standard error of that difference."""
        i0, ik = self.argmin(0.0), self.argmin(kappa)
        f = self.boot_mean + kappa * self.boot_std
        return float(self.objective(kappa)[i0] - self.objective(kappa)[ik]), float((f[:, i0] - f[:, ik]).std(ddof=1))

    def rows(self) -> list[dict[str, float]]:
        se_m, se_s, se_f = self.boot_mean.std(axis=0, ddof=1), self.boot_std.std(axis=0, ddof=1), self.se(2.0)
        return [{"theta": float(t), "stiffness": float(k), "mean": float(m), "mean_se": float(a),
                 "std": float(s), "std_se": float(b), "F2": float(m + 2 * s), "F2_se": float(c),
                 "damage": float(d), "fallen": float(f), **{n: float(v) for n, v in zip(TERMS, tm)}}
                for t, k, m, a, s, b, c, d, f, tm in zip(
                    self.thetas, self.stiffness, self.mean, se_m, self.std, se_s, se_f,
                    self.damage.mean(axis=1), self.fallen.mean(axis=1), self.terms)]

    def markdown(self) -> str:
        head = ("| theta | K (N m/rad) | mean J | std J | F2 = mean + 2 std | damage | fallen | "
                + " | ".join(TERMS) + " |")
        lines = [head, "|" + "---|" * (7 + len(TERMS))]
        for r in self.rows():
            lines.append(f"| {r['theta']:.2f} | {r['stiffness']:.1f} | {r['mean']:.1f} +- {r['mean_se']:.1f} "
                         f"| {r['std']:.1f} +- {r['std_se']:.1f} | {r['F2']:.1f} +- {r['F2_se']:.1f} "
                         f"| {r['damage']:.2f} | {r['fallen']:.2f} | "
                         + " | ".join(f"{r[t]:.2f}" for t in TERMS) + " |")
        lines.append("")
        for kappa in KAPPAS:
            i = self.argmin(kappa)
            lines.append(f"argmin mean + {kappa:g} std: theta {self.thetas[i]:.2f} "
                         f"(F {self.objective(kappa)[i]:.1f} +- {self.se(kappa)[i]:.1f})")
        g, se = self.gap(2.0)
        lines.append(f"F2 at the kappa-0 optimum minus F2 at the kappa-2 optimum: {g:.1f} "
                     f"(bootstrap SE {se:.1f}, {g / se if se > 0 else float('inf'):.1f} SE)")
        return "\n".join(lines)

    def plot(self, path: Path) -> None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 4.5))
        m, s = self.mean, self.std
        ax.fill_between(self.thetas, m - 2 * s, m + 2 * s, alpha=0.25, label="mean +- 2 std")
        ax.plot(self.thetas, m, "o-", label="mean J")
        ax.plot(self.thetas, m + 2 * s, "--", label="F2 = mean + 2 std")
        for kappa, c in ((0.0, "k"), (2.0, "r")):
            ax.axvline(self.thetas[self.argmin(kappa)], color=c, lw=1, ls=":",
                       label=f"argmin kappa {kappa:g}")
        ax.set_xlabel("theta (arm stiffness)")
        ax.set_ylabel("cost J")
        ax2 = ax.twinx()
        ax2.bar(self.thetas, self.damage.mean(axis=1), width=0.03, color="tab:red", alpha=0.35,
                label="damage rate")
        ax2.set_ylim(0, 1)
        ax2.set_ylabel("damage rate")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, loc="upper center", fontsize=8)
        ax.set_title(f"bracing landscape, {self.J.shape[1]} episodes per theta")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=30, help="episodes (seeds) per theta")
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first .. first + episodes - 1")
    ap.add_argument("--step", type=float, default=0.05, help="theta grid step over [0, 1]")
    ap.add_argument("--thetas", default=None, help="comma-separated theta grid (overrides --step)")
    ap.add_argument("--bootstrap", type=int, default=1000, help="bootstrap replicates")
    ap.add_argument("--out", type=Path, default=None, help="directory for landscape.{md,json,png}")
    ap.add_argument("--per-episode", action="store_true", help="also print every episode")
    args = ap.parse_args()
    if args.episodes < 2 or not 0 < args.step <= 1:
        ap.error("--episodes must be >= 2 and --step in (0, 1]")
    thetas = ([float(t) for t in args.thetas.split(",")] if args.thetas
              else [round(x, 6) for x in np.arange(0.0, 1.0 + 1e-9, args.step)])
    t0 = time.perf_counter()
    results = sweep(thetas, args.episodes, args.first_seed)
    wall = time.perf_counter() - t0
    weights = TASKS["bracing"].default_weights
    print(f"bracing landscape: {len(thetas)} thetas x {args.episodes} seeds through the virtual-bus "
          f"stack, J = " + " + ".join(f"{w:g} {n}" for n, w in weights.items()))
    if args.per_episode:
        for theta, rs in results.items():
            for r in rs:
                p = r.telemetry.get("bench_impact_momentum_ns", float("nan"))
                print(f"theta {theta:4.2f} p {p:5.2f} J {r.total_cost:7.1f} "
                      + " ".join(f"{k} {v:8.2f}" for k, v in r.cost_terms.items()))
    land = Landscape.from_results(results, args.bootstrap)
    print(land.markdown())
    n = len(thetas) * args.episodes
    print(f"{n} episodes in {wall:.0f} s ({wall / n:.2f} s per episode, load average "
          f"{os.getloadavg()[0]:.1f})")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "landscape.md").write_text(land.markdown() + "\n")
        g, se = land.gap(2.0)
        doc = {"episodes": args.episodes, "first_seed": args.first_seed, "weights": dict(weights),
               "rows": land.rows(),
               "argmin": {f"{k:g}": float(land.thetas[land.argmin(k)]) for k in KAPPAS},
               "F2_gap": g, "F2_gap_se": se,
               "episodes_detail": {f"{t:.2f}": [{"seed": args.first_seed + i, "total_cost": r.total_cost,
                                                  "terms": dict(r.cost_terms),
                                                  "momentum": r.telemetry.get("bench_impact_momentum_ns")}
                                                 for i, r in enumerate(rs)]
                                   for t, rs in results.items()}}
        (args.out / "landscape.json").write_text(json.dumps(doc, indent=1))
        land.plot(args.out / "landscape.png")
        print(f"wrote {args.out}/landscape.md, landscape.json, landscape.png")


if __name__ == "__main__":
    main()
