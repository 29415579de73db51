"""Simulator speed: bare physics real-time factor per scenario, and lock-step cycles per
second through the whole CAN stack (SimulatedRobot nodes <-> a canopen master) per backend.

    python bench/sim_speed.py [--cycles N]

Prints a table; no pass/fail. One lock-step cycle = the master sends the wheel and arm RPDOs
and SYNC, the robot applies them, steps 5 ms of physics, and the master waits for all 13
synchronous TPDOs.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


from ersac_hil.canbus import LoopbackHub, vcan_status  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter  # noqa: E402
from firmware_sim.nodes.simrobot import SimulatedRobot  # noqa: E402
from protocol.can import cobid  # noqa: E402
from protocol.can.devices import DEVICES, SYNC_PERIOD_S, object_dictionary  # noqa: E402
from protocol.can.busconfig import BusConfig, open_network  # noqa: E402
from protocol.can.pdo import cyclic_pdos  # noqa: E402
import sim_physics  # noqa: E402


def can_cycles_per_second(config: BusConfig, cycles: int) -> tuple[float, float, float]:
    """(cycles/s, p50 ms, p99 ms) of lock-step cycles over ``config``."""
    robot = SimulatedRobot(config)
    net = open_network(config)
    try:
        nodes = [net.add_node(d.node_id, object_dictionary(d)) for d in DEVICES]
        tpdos = [p.cob_id for p in cyclic_pdos() if p.direction == "tpdo"]
        got = threading.Semaphore(0)
        for c in tpdos:
            net.subscribe(c, lambda *a: got.release())
        rpdos = []
        for node in nodes:
            node.rpdo.read(from_od=True)
            rpdos += [m for m in node.rpdo.map.values() if m.enabled]
        net.nmt.state = "OPERATIONAL"
        time.sleep(0.1)
        lat = []
        t_start = time.perf_counter()
        for _ in range(cycles):
            t0 = time.perf_counter()
            for m in rpdos:
                m.transmit()
            net.send_message(cobid.SYNC, b"")
            for _ in tpdos:
                if not got.acquire(timeout=1.0):
                    raise RuntimeError("TPDO missing")
            lat.append(time.perf_counter() - t0)
        total = time.perf_counter() - t_start
    finally:
        net.disconnect()
        robot.close()
    lat.sort()
    return cycles / total, 1000 * lat[len(lat) // 2], 1000 * lat[int(0.99 * (len(lat) - 1))]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=1000)
    args = ap.parse_args()
    print("physics only (bench/sim_physics.py: Simulator.step with an LQR, no CAN):")
    sim_physics.report(repeat=2)
    print(f"\nlock-step through the CAN stack ({args.cycles} cycles, 4 RPDOs + SYNC + 13 TPDOs each):")
    print(f"{'backend':<32} {'cycles/s':>9} {'RTF':>6} {'p50 ms':>7} {'p99 ms':>7}")
    vc = vcan_status()
    for name in ("virtual", "remote (loopback hub)", "zenoh (embedded router)"):
        with contextlib.ExitStack() as stack:
            if name == "virtual":
                config = BusConfig("virtual", "bench-speed")
            elif name.startswith("remote"):
                config = stack.enter_context(LoopbackHub()).bus_config
            else:
                router = stack.enter_context(EmbeddedRouter())
                config = BusConfig("zenoh", f"bench-speed@{router.endpoint}")
            rate, p50, p99 = can_cycles_per_second(config, args.cycles)
        print(f"{name:<32} {rate:>9.0f} {rate * SYNC_PERIOD_S:>5.1f}x {p50:>7.2f} {p99:>7.2f}", flush=True)
    if vc.available:
        rate, p50, p99 = can_cycles_per_second(BusConfig("socketcan", "vcan0"), args.cycles)
        print(f"{'socketcan vcan0':<32} {rate:>9.0f} {rate * SYNC_PERIOD_S:>5.1f}x {p50:>7.2f} {p99:>7.2f}")
    else:
        print(f"{'socketcan vcan0':<32} skipped: {vc.reason}")


if __name__ == "__main__":
    main()
