"""How fast faults are noticed: the timing figures the tests do not assert.

    python bench/fault_latency.py [--reps N]

Per CAN backend (``virtual`` in this process, ``remote`` through a loopback hub in this
process), against the simulated robot (``SimulatedRobot``) in real time (the deadlines of a
real robot; lock-step waits generously for a simulator a loaded machine stalls, see
``ersac_hil.agent.bus``), N repetitions of:

* heartbeat loss: the agent's heartbeat stops -> EMCY 0x8130 from every controller (target:
  within 3 agent heartbeat periods + 100 ms, 0.4 s: the controllers consume it with 250 ms);
* missing TPDO: the IMU node leaves the bus -> ``PdoTimeout`` of the next cycle (target < 1 s);
* robot gone: every node leaves mid-run -> ``AgentFault`` (target < 1 s);
* no simulator: an episode on an empty bus -> ``fault_simulator`` (target < 3 s).

Prints median and maximum per figure beside its target, and the load average: the figures
move with what else runs on the machine. No pass/fail.
"""
from __future__ import annotations

import argparse
import logging
import os
import statistics
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ersac_hil.agent.bus import AgentBus, BusTiming  # noqa: E402
from ersac_hil.agent.episode import EpisodeRunner  # noqa: E402
from ersac_hil.agent.errors import AgentFault, PdoTimeout  # noqa: E402
from ersac_hil.agent.telemetry import ACTUATED  # noqa: E402
from ersac_hil.canbus import LoopbackHub  # noqa: E402
from firmware_sim.nodes.simrobot import SimulatedRobot  # noqa: E402
from protocol.can.busconfig import BusConfig  # noqa: E402
from protocol.can.objects import EmcyCode  # noqa: E402
from protocol.zenoh import EpisodeRequest  # noqa: E402

TARGETS_S = {"heartbeat loss -> EMCY": 0.4, "missing TPDO -> PdoTimeout": 1.0,
             "robot gone -> fault": 1.0, "no simulator -> fault": 3.0}


@contextmanager
def backend(kind: str) -> Iterator[BusConfig]:
    if kind == "virtual":
        yield BusConfig("virtual", f"fault-{uuid.uuid4().hex[:8]}")
    else:
        with LoopbackHub() as hub:
            yield hub.bus_config


@contextmanager
def rig(config: BusConfig) -> Iterator[tuple[SimulatedRobot, AgentBus]]:
    robot = SimulatedRobot(config, realtime=True)
    try:
        with AgentBus(config, timing=BusTiming(realtime=True)) as bus:
            bus.wait_for_nodes()
            bus.nmt_start()
            bus.cycle()
            yield robot, bus
    finally:
        robot.close()


def heartbeat_loss(config: BusConfig) -> float:
    with rig(config) as (_, bus):
        names = {d.name for d in ACTUATED}
        t0 = time.perf_counter()
        bus.stop_heartbeat()
        while not names <= {e.device for e in bus.emcy_events() if e.code == EmcyCode.HEARTBEAT_LOST}:
            if time.perf_counter() - t0 > 10:
                raise RuntimeError("no EMCY 0x8130 from every controller within 10 s")
            time.sleep(0.001)
        return time.perf_counter() - t0


def _fault_after(config: BusConfig, remove: Callable[[SimulatedRobot], None],
                 expected: type[AgentFault]) -> float:
    with rig(config) as (robot, bus):
        remove(robot)
        t0 = time.perf_counter()
        try:
            for _ in range(1000):
                bus.cycle()
        except expected:
            return time.perf_counter() - t0
        raise RuntimeError(f"no {expected.__name__} after 1000 cycles")


def missing_tpdo(config: BusConfig) -> float:
    return _fault_after(config, lambda robot: robot.nodes["imu"].close(), PdoTimeout)


def robot_gone(config: BusConfig) -> float:
    def remove_all(robot: SimulatedRobot) -> None:
        for node in robot.nodes.values():
            node.close()
    return _fault_after(config, remove_all, AgentFault)


def no_simulator(config: BusConfig) -> float:
    with AgentBus(config, timing=BusTiming(realtime=True)) as bus:
        runner = EpisodeRunner(bus)
        t0 = time.perf_counter()
        result = runner.run(runner.plan(EpisodeRequest("bench", "bracing", (0.5,), 0)))
        elapsed = time.perf_counter() - t0
    if result.status != "fault_simulator":
        raise RuntimeError(f"expected fault_simulator, got {result.status}")
    return elapsed


FIGURES: dict[str, Callable[[BusConfig], float]] = {
    "heartbeat loss -> EMCY": heartbeat_loss, "missing TPDO -> PdoTimeout": missing_tpdo,
    "robot gone -> fault": robot_gone, "no simulator -> fault": no_simulator}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5, help="repetitions per figure (default 5)")
    args = parser.parse_args(argv)
    if args.reps < 1:
        parser.error("--reps must be at least 1")
    logging.disable(logging.CRITICAL)  # the nodes log every fault this script provokes
    print(f"load average at start {' '.join(f'{v:.1f}' for v in os.getloadavg())}; {args.reps} reps\n")
    print("| backend | figure | median s | max s | target s |\n|---|---|---|---|---|")
    for kind in ("virtual", "remote"):
        for name, measure in FIGURES.items():
            times = []
            for _ in range(args.reps):
                with backend(kind) as config:
                    times.append(measure(config))
            print(f"| {kind} | {name} | {statistics.median(times):.3f} | {max(times):.3f} | "
                  f"{TARGETS_S[name]:g} |", flush=True)
    print(f"\nload average at the end {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
