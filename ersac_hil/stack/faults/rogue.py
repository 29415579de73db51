"""Faulty nodes on the robot's CAN bus: a rogue bus on the simulator's CAN-over-Zenoh listener
sending what no node of the robot should (a second SYNC, forged or short PDOs, stray SDO
answers, a babbler, error frames) while an episode runs."""
from __future__ import annotations

import dataclasses
import time

from .history import history
from .outcome import RUN_S, Outcome, finish, mid_episode
from .rig import Rig

__all__ = ["ROGUE_NODES", "ROGUE_TICK_S", "robot_cob_ids", "rogue_can", "rogue_frames"]

ROGUE_NODES: dict[str, str] = {
    "sync": "a second SYNC producer",
    "tpdo-twice": "a second producer of the IMU's TPDO, of the right length (twice in one cycle)",
    "wrong-length": "the IMU's TPDO one byte short",
    "sdo-answer": "SDO answers nobody asked for, on the agent's SDO client COB-ID of the IMU",
    "babbler": "a babbling node flooding the high-priority COB-ID 0x001 (50 frames a tick)",
    "error-frame": "error frames",
}
"""The faulty CAN nodes of :func:`rogue_can`: kind -> what it sends every ``ROGUE_TICK_S``."""
ROGUE_TICK_S = 0.02


def robot_cob_ids() -> set[int]:
    """Every COB-ID of the robot's own traffic (the board profile): NMT, SYNC, every node's
    PDOs, EMCY, SDO requests and answers and heartbeats, and the agent's heartbeat."""
    from protocol.can import AGENT_NODE_ID, cobid
    from protocol.can.devices import DEVICES
    from protocol.can.pdo import pdo_maps

    ids = {cobid.NMT, cobid.SYNC, cobid.heartbeat(AGENT_NODE_ID)}
    for dev in DEVICES:
        ids |= {p.cob_id for p in pdo_maps(dev)}
        ids |= {cobid.emcy(dev.node_id), cobid.sdo_rx(dev.node_id), cobid.sdo_tx(dev.node_id),
                cobid.heartbeat(dev.node_id)}
    return ids


def rogue_frames(kind: str) -> list:
    """The frames the rogue node of ``kind`` (of :data:`ROGUE_NODES`) sends every tick."""
    import can

    from protocol.can import cobid
    from protocol.can.devices import DEVICES
    from protocol.can.pdo import pdo_maps, pdo_struct

    def frame(cob_id: int, data: bytes = b"", error: bool = False) -> can.Message:
        return can.Message(arbitration_id=cob_id, data=data, is_error_frame=error, is_extended_id=False)
    imu = next(d for d in DEVICES if d.name == "imu")
    tpdo = min((p for p in pdo_maps(imu) if p.direction == "tpdo" and 1 <= p.transmission_type <= 240),
               key=lambda p: p.cob_id)  # a synchronous TPDO: exactly one a SYNC cycle
    size = pdo_struct(tpdo).size
    makers = {
        "sync": lambda: [frame(cobid.SYNC)],
        "tpdo-twice": lambda: [frame(tpdo.cob_id, bytes([0x55] * size))],
        "wrong-length": lambda: [frame(tpdo.cob_id, bytes(size - 1))],
        "sdo-answer": lambda: [frame(cobid.sdo_tx(imu.node_id), bytes([0x43, 0x18, 0x10, 1, 0, 0, 0, 0]))],
        "babbler": lambda: [frame(0x001, bytes(8))] * 50,
        "error-frame": lambda: [frame(0x000, bytes(8), error=True)],
    }
    return makers[kind]()


def rogue_can(rig: Rig, kind: str = "sync", *more: str, after: int = 2) -> Outcome:
    """A rogue node on the robot's CAN bus mid-episode (its own bus on the simulator's listener)
    sending the frames of ``kind`` (:data:`ROGUE_NODES`) every ``ROGUE_TICK_S`` while the episode
    it hit runs (the attempt pending once ``after`` episodes are ok), then gone: however that
    attempt ended (a bus fault, or ok if the agent missed the node), the run goes on without the
    node. Each of ``more`` kinds then hits the next episode the same way (its attempt pending
    once the one before is ok). ``during``: the store when the first node came; ``hits``: (kind,
    idx, attempt) of every attempt a node hit."""
    import can

    rig.start()
    rogue = can.Bus(interface="zenoh", channel=rig.can_channel)

    def running(hit: tuple[int, int]) -> bool:
        h = history(rig.db)
        return h is None or any((idx, attempt) == hit and status == "pending" for idx, attempt, status in h.attempts)
    hits, during, t_fault = [], None, None
    try:
        for n, name in enumerate((kind, *more)):
            frames = rogue_frames(name)
            seen = mid_episode(rig, after + n)
            (hit,) = [(idx, attempt) for idx, attempt, status in seen.attempts if status == "pending"]
            hits.append((name, *hit))
            if during is None:
                during, t_fault = seen, time.monotonic()
            deadline = time.monotonic() + RUN_S
            while running(hit):
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the episode under {ROGUE_NODES[name]} did not end")
                for msg in frames:
                    rogue.send(msg)
                time.sleep(ROGUE_TICK_S)  # the node's own rate, not a synchronisation
    finally:
        rogue.shutdown()
    outcome = finish(rig, "rogue-" + "+".join((kind, *more)), during, (), t_fault, time.time())
    return dataclasses.replace(outcome, hits=tuple(hits))
