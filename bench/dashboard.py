"""Latency from an episode's result to its point on the dashboard page.

Runs ``ersac-hil demo --dashboard --linger`` (the whole stack: router, CAN hub, MuJoCo simulator,
agent, daemon, dashboard), opens the page in headless Chromium (Debian's, via Selenium), listens
to the agent's ``episode/done`` publications, and when the run is over reads, for every episode
the page received live, when its point was drawn (after Plotly's ``extendTraces`` and the next
animation frame). Prints p50 / p99 / max of:

* agent result -> point drawn: from the agent's ``EpisodeDone.stamp_s`` (the result, before the
  learner's update) to the frame showing the point;
* learner publication -> point drawn: from ``LearnerEpisode.stamp_s`` (after the learner's update
  and commit) to that frame: the dashboard's own share;
* learner publication -> event in the page: the same without drawing;
* learner publication -> a plain Zenoh subscriber in this process: the floor (baseline, same run).

All clocks are this machine's wall clock. Writes the cumulative distributions as a PNG
(``--plot``) and, with ``--screenshot PNG``, a screenshot of the page at the end of the run.

    python bench/dashboard.py [--episodes 30] [--seed 1] [--plot dashboard_latency.png] [--screenshot dashboard.png]
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from ersac_hil.dashboard.browser import headless_chromium, missing  # noqa: E402
from ersac_hil.stack import Child  # noqa: E402
from ersac_hil.zenoh_session import make_config, open_session  # noqa: E402
from protocol.zenoh import EpisodeDone, KeySpace, LearnerEpisode  # noqa: E402

ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl",
       "PYTHONUNBUFFERED": "1"}


def _row(name: str, values_ms: list[float]) -> str:
    v = np.asarray(values_ms)
    return (f"{name:<38} n {len(v):3d}  p50 {np.percentile(v, 50):7.1f} ms  p99 {np.percentile(v, 99):7.1f} ms"
            f"  max {v.max():7.1f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--plot", default="dashboard_latency.png", help="latency PNG ('' = none)")
    parser.add_argument("--screenshot", default="", metavar="PNG",
                        help="also a screenshot of the page at the end of the run (docs/dashboard.png)")
    args = parser.parse_args(argv)
    reason = missing()
    if reason:
        print(f"bench/dashboard.py: no headless browser: {reason}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="dashboard-bench-") as tmp:
        tmp_path = Path(tmp)
        demo = Child("demo", [sys.executable, "-m", "ersac_hil.cli", "demo", "--out", str(tmp_path / "out"),
                              "--episodes", str(args.episodes), "--seed", str(args.seed), "--dashboard",
                              "--dashboard-port", "0", "--linger"], tmp_path, ENV)
        driver = session = None
        done_stamps: dict[str, float] = {}
        floor_ms: list[float] = []
        lock = threading.Lock()

        def on_episode(sample) -> None:  # noqa: ANN001
            now = time.time()
            episode = LearnerEpisode.from_json(sample.payload)
            with lock:
                floor_ms.append(1000 * (now - episode.stamp_s))

        def on_done(sample) -> None:  # noqa: ANN001
            done = EpisodeDone.from_json(sample.payload)
            with lock:
                done_stamps[done.result.episode_id] = done.stamp_s

        try:
            endpoint = demo.wait_for(r"^demo: router (tcp/\S+),", 120).group(1)
            session = open_session(make_config("client", connect=[endpoint]))
            keys = KeySpace("ubot1")
            session.declare_subscriber(keys.episode_done, on_done)
            session.declare_subscriber(keys.learner_episodes, on_episode)
            url = demo.wait_for(r"^demo: dashboard (http://\S+)", 60).group(1)
            driver = headless_chromium(tmp_path / "chromium")
            driver.get(url)
            print(f"dashboard {url}; {args.episodes} episodes ...", flush=True)
            demo.wait_for(r"^demo: stack up on", 60 + 30 * args.episodes)
            records = driver.execute_script("return window.dashboard.latency;")
            load = os.getloadavg()
            if args.screenshot:  # Selenium's: chromium --screenshot never returns on this live page
                driver.save_screenshot(args.screenshot)
                print(f"screenshot in {Path(args.screenshot).resolve()}")
        finally:
            if driver is not None:
                driver.quit()
            if session is not None:
                session.close()
            os.killpg(demo.pid, signal.SIGINT)
            demo.stop()
    with lock:
        agent = [r["shown_ms"] - 1000 * done_stamps[r["episode_id"]] for r in records
                 if r["episode_id"] in done_stamps]
    learner = [r["shown_ms"] - 1000 * r["stamp_s"] for r in records]
    received = [r["received_ms"] - 1000 * r["stamp_s"] for r in records]
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (2 cores, shared)")
    print(_row("agent result -> point drawn", agent))
    print(_row("learner publication -> point drawn", learner))
    print(_row("learner publication -> event in page", received))
    print(_row("learner publication -> Zenoh subscriber", floor_ms))
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 4.6), constrained_layout=True)
        # cumulative distributions: two overlaid histograms of ~30 values hide each other
        for values, label, colour in ((agent, "agent result -> point drawn", "tab:blue"),
                                      (learner, "learner publication -> point drawn", "tab:orange"),
                                      (floor_ms, "learner publication -> Zenoh subscriber", "tab:grey")):
            v = np.sort(np.asarray(values, dtype=float))
            if not v.size:
                continue
            ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", color=colour,
                    label=f"{label} (median {np.median(v):.0f} ms)")
            ax.plot(np.median(v), 0.5, "o", color=colour)
        ax.set_xlabel("latency [ms]")
        ax.set_ylabel("fraction of episodes")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.set_title(f"episode -> point on the dashboard ({len(records)} episodes, load {load[0]:.1f})")
        fig.legend(loc="outside lower center", fontsize=8, frameon=False)  # off the curves
        fig.savefig(args.plot, dpi=110)
        print(f"histogram in {Path(args.plot).resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
