"""``commission --move AXIS``: one axis enabled at low stiffness, a small motion and back.

The check of direction, sign and scaling before the learner moves an axis: the axis's board
gets a low stiffness (a tenth of the description's ``stiffness_range`` maximum, damping time
10 ms), setpoints at the measured positions of its axes, and then, paced by the wall clock at
the description's SYNC period, the moved axis's setpoint ramps by ``angle`` (towards the middle
of its range) and back. Only that node's RPDO carries ENABLE; every other node stays disabled.
At the end the node's control word goes back to 0 and its status word (0x2010) is read until
it reports operation disabled (``MoveFailed`` if it does not within ``DISABLE_CONFIRM_S``); on any
error or Ctrl-C the control word goes back to 0 too; then every node goes to pre-operational. A wheel (a torque axis) moves the robot: it is not offered here.
"""
from __future__ import annotations

import time
from collections.abc import Iterator

import canopen

from ersac_hil.canbus.heartbeat import HeartbeatProducer
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ersac_hil.commission.scan import NoAnswer, read_value
from protocol.can import cobid
from protocol.can.busconfig import BusConfig, open_network
from protocol.can.objects import POSITION, STIFFNESS, DAMPING, Control, Index, Status
from protocol.can.pdo import pdo_maps, pdo_struct
from protocol.robot import RobotDescription
from protocol.robot.eds import object_dictionary_file

DISABLE_CONFIRM_S = 1.0
"""How long the node may take to report its axis disabled after the move (status 0x2010)."""


class MoveRefused(Exception):
    """The axis cannot be moved this way (the reason says why); nothing moved."""


class MoveFailed(MoveRefused):
    """The node stopped answering during the move (it was disabled again), or did not report
    its axis disabled after it."""


def move_axis(description: RobotDescription, bus: BusConfig, axis_name: str, angle: float = 0.05,
              seconds: float = 2.0, sdo_timeout_s: float = 0.3) -> Iterator[str]:
    """Move ``axis_name`` by ``angle`` [rad] and back over ``seconds``; yields report lines.
    ``MoveRefused`` before anything moved, ``MoveFailed`` when the node stopped answering."""
    axis = description.axis(axis_name)
    if axis.profile != "ubot-board":
        raise MoveRefused(f"{axis.name} is a {axis.profile} axis: --move drives ubot-board axes only; "
                          "move a CiA 402 axis with its vendor's tool")
    if not axis.impedance or axis.position_limits is None:
        raise MoveRefused(f"{axis.name} is a torque axis (a wheel moves the robot): not moved")
    dev = description.device(axis.node)
    od = object_dictionary_file(dev.eds, dev.node_id)
    (rpdo,) = [p for p in pdo_maps(dev) if p.direction == "rpdo" and p.number == 1]
    pack = pdo_struct(rpdo).pack
    stiffness = axis.stiffness_range.max / 10.0
    damping = min(0.01 * stiffness, axis.damping_range.max)
    period = description.bus.sync_period_s
    network = open_network(bus)
    heartbeat = HeartbeatProducer(network, description.bus.agent_node_id).start()
    node = canopen.RemoteNode(dev.node_id, od)
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    enabled = False
    start: dict[int, float] = {}

    def send(control: int, setpoints: dict[int, float]) -> None:
        values = {(Index.CONTROL, 0): control,
                  **{(Index.POSITION_SETPOINT, sub): POSITION.to_raw(q) for sub, q in setpoints.items()}}
        network.send_message(rpdo.cob_id, pack(*(values.get(k, 0) for k in rpdo.keys)))
        network.send_message(cobid.SYNC, b"")

    def position(sub: int) -> float:
        return POSITION.from_raw(int(read_value(node.sdo, od, Index.POSITION, sub)))

    try:
        subs = [a.subindex for a in description.node_axes(axis.node)]
        start = {sub: position(sub) for sub in subs}
        low, high = axis.position_limits.min, axis.position_limits.max
        q0 = start[axis.subindex]
        step = angle if q0 + angle <= high and (q0 - low) <= (high - q0) else -angle
        if not low <= q0 + step <= high:
            raise MoveRefused(f"{axis.name} at {q0:.4f} rad: no room for {angle:g} rad inside "
                              f"[{low:g}, {high:g}] rad")
        for sub in subs:
            node.sdo.download(Index.STIFFNESS, sub, od[Index.STIFFNESS][sub].encode_raw(STIFFNESS.to_raw(stiffness)))
            node.sdo.download(Index.DAMPING, sub, od[Index.DAMPING][sub].encode_raw(DAMPING.to_raw(damping)))
        yield (f"{axis.name}: {dev.name} 0x{dev.node_id:02X} at stiffness {stiffness:g} N m/rad, "
               f"damping {damping:g} N m s/rad; from {q0:.4f} rad by {step:+g} rad and back in {seconds:g} s")
        network.nmt.state = "OPERATIONAL"
        n = max(2, int(round(seconds / period)))
        t_next, peak = time.perf_counter(), q0
        for i in range(n + 1):
            ramp = 1.0 - abs(2.0 * i / n - 1.0)  # 0 -> 1 -> 0
            send(int(Control.ENABLE), {**start, axis.subindex: q0 + step * ramp})
            enabled = True
            if i == n // 2:
                peak = position(axis.subindex)
            t_next += period
            time.sleep(max(0.0, t_next - time.perf_counter()))
        end = position(axis.subindex)
        send(0, start)  # disabled again, and confirmed by the node (the SDO answer comes after the SYNC)
        deadline = time.monotonic() + DISABLE_CONFIRM_S
        while Status(int(read_value(node.sdo, od, Index.STATUS, 0))) & Status.OPERATION_ENABLED:
            if time.monotonic() > deadline:
                raise MoveFailed(f"{dev.name} 0x{dev.node_id:02X} still reports operation enabled "
                                 f"{DISABLE_CONFIRM_S:g} s after the disable")
            send(0, start)
            time.sleep(period)
        enabled = False
    except (SdoCommunicationError, SdoAbortedError, NoAnswer) as exc:
        raise MoveFailed(f"{dev.name} 0x{dev.node_id:02X}: {exc}") from None
    else:
        yield (f"{axis.name}: reached {peak:.4f} rad at the turn (asked {q0 + step:.4f}), back at {end:.4f} rad; "
               f"moved {peak - q0:+.4f} rad for {step:+g} asked")
    finally:
        try:
            if enabled:
                send(0, start)
            network.nmt.state = "PRE-OPERATIONAL"
        finally:
            heartbeat.stop()
            network.disconnect()
