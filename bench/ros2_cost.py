"""What the ROS 2 bridge and MCAP recording cost the agent, in CPU as well as in wall time.

    python bench/ros2_cost.py [--rounds 3] [--episodes 3] [--task bracing]

Per round, three agents one after the other (off, ``--ros2``, ``--ros2 --record DIR``), each
with its simulated robot in this process on a virtual bus and a Zenoh router, run the same
lock-step episodes (same seed and theta). Printed per round and variant: the median episode
wall time, this process's CPU time per SYNC cycle (agent, simulator, the feed thread that hands
the raw samples on, Zenoh threads: ``time.process_time``; the feed thread's own share from
``/proc``, resolution 10 ms) and the feed process's CPU per cycle
(the agent's child that serializes, publishes and writes the MCAP files, from ``/proc``: from
the agent's ready - its imports, session and ``messages.warm_up`` done - until it has caught
up after the last episode, so its work on the episodes, not its start and exit), with the load
average. CPU per cycle is the figure a shared machine disturbs least; wall time is what the
issue's 10 % target is about. No pass/fail.
OPENBLAS_NUM_THREADS=1.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ersac_hil.agent.service import AgentConfig, AgentService  # noqa: E402
from ersac_hil.ros2.options import Ros2Options  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter  # noqa: E402
from firmware_sim.nodes.simrobot import SimulatedRobot  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace  # noqa: E402

THETA = {"bracing": (0.5,), "lifting": (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2)}
VARIANTS = ("off", "--ros2", "--ros2 --record")


def _thread_cpu(name: str) -> float:
    """CPU time [s] of this process's thread ``name`` (Linux ``/proc``; 0 without it)."""
    for t in threading.enumerate():
        if t.name == name and t.native_id is not None:
            fields = Path(f"/proc/self/task/{t.native_id}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return 0.0


def _pid_cpu(pid: int) -> float:
    """CPU time [s] of process ``pid`` so far (Linux ``/proc``; 0 without it)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _settled_cpu(pid: int, timeout_s: float = 10.0) -> float:
    """``_pid_cpu(pid)`` once it has stopped growing for 0.3 s (the feed process caught up)."""
    deadline, last = time.monotonic() + timeout_s, -1.0
    while time.monotonic() < deadline:
        now = _pid_cpu(pid)
        if now == last:
            return now
        last = now
        time.sleep(0.3)
    return last


def run(variant: str, task: str, episodes: int, record: Path) -> tuple[list[float], float, float, float, int]:
    """(episode wall times, process CPU, the feed thread's CPU and the feed process's CPU from
    its ready on (its start-up not counted) per cycle [ms], cycles)."""
    bus = BusConfig("virtual", f"cost-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("cost")
    robot = SimulatedRobot(bus)
    walls, cycles = [], 0
    try:
        with EmbeddedRouter() as router, router.open_client() as session:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,),
                                 ros2=Ros2Options() if variant != "off" else None,
                                 record=str(record) if "--record" in variant else None)
            with AgentService(config) as agent:
                while not list(session.liveliness().get(keys.agent_alive, timeout=1)):
                    time.sleep(0.05)
                feeding = getattr(agent, "feed", None)
                started = _pid_cpu(feeding.process.pid) if feeding is not None else 0.0  # imports, session, warm-up
                cpu0, feed0 = time.process_time(), _thread_cpu("ros2-feed")
                for i in range(episodes):
                    request = EpisodeRequest(f"cost-{uuid.uuid4().hex[:8]}", task, THETA[task], 7 + i)
                    t0 = time.perf_counter()
                    (reply,) = list(session.get(keys.episode_run, payload=request.to_json(), timeout=120))
                    walls.append(time.perf_counter() - t0)
                    cycles += round(EpisodeResult.from_json(reply.ok.payload).telemetry["n_cycles"])
                cpu, feed = time.process_time() - cpu0, _thread_cpu("ros2-feed") - feed0
                writer = _settled_cpu(feeding.process.pid) - started if feeding is not None else 0.0
    finally:
        robot.close()
    return walls, cpu / cycles * 1e3, feed / cycles * 1e3, writer / cycles * 1e3, cycles


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--task", choices=tuple(THETA), default="bracing")
    args = p.parse_args()
    print(f"lock-step {args.task}, {args.episodes} episodes per variant and round, virtual bus in this process")
    with tempfile.TemporaryDirectory(prefix="ros2-cost-") as tmp:
        for rnd in range(1, args.rounds + 1):
            print(f"round {rnd}  load average {os.getloadavg()[0]:.2f}")
            for variant in VARIANTS:
                walls, cpu, feed, writer, cycles = run(variant, args.task, args.episodes, Path(tmp))
                print(f"  {variant:<16} wall {statistics.median(walls):5.2f} s (median of {len(walls)})  "
                      f"process CPU {cpu:5.3f} ms/cycle (feed thread {feed:5.3f})  "
                      f"feed process CPU {writer:5.3f} ms/cycle  "
                      f"({cycles} cycles)", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
