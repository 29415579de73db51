"""The episodes' ROS 2 messages, made in the feed process (``writer``) from what the agent
handed on as it was: each cycle's ``Telemetry``, the bus's EMCY events, the CAN frames of its
tap, an episode's request and result.

Per episode (``begin`` ... ``end``): the ``episode`` message at the start and the end, per cycle
``joint_states`` and ``imu`` (to the live node every ``decimation``-th cycle, to the file every
cycle), ``diagnostics`` when a status word changes, on an EMCY, at least every
``DIAGNOSTICS_EVERY`` cycles and at a fault, the events (``foxglove_msgs/msg/Log``) and the CAN
frames (file only). Every message is serialized once (rosbags' CDR, ``messages``; the per-cycle
ones and the CAN frames by its fast paths, the same bytes) and the same bytes go to the live
node (``bridge.Ros2Node``) and the episode's MCAP file (``recorder.McapEpisodes``), either of
which may be absent.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ersac_hil.agent.bus import EmcyEvent
from ersac_hil.agent.telemetry import Telemetry
from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.bridge import Ros2Node
from ersac_hil.ros2.recorder import McapEpisodes
from protocol.zenoh import EpisodeRequest, EpisodeResult

DIAGNOSTICS_EVERY = 200
"""Cycles between two diagnostics when nothing changed (1 s at 200 Hz)."""


@dataclass
class _Episode:
    request: EpisodeRequest
    start_ns: int
    period_ns: int
    first_cycle: int | None = None
    index: int = 0
    status: tuple[int, ...] = ()
    last_diagnostics: int = 0
    emcy: list[EmcyEvent] = field(default_factory=list)  # heard, not yet published

    def stamp(self, cycle: int) -> int:
        """The robot's time of a cycle: the episode's start plus SYNC periods."""
        if self.first_cycle is None:
            self.first_cycle = cycle
        return self.start_ns + (cycle - self.first_cycle) * self.period_ns


class EpisodeStream:
    """``begin``, ``cycle``/``emcy``/``frames``, ``end`` (the feed's records, ``writer``).

    Args:
        robot: the robot's name (diagnostic names ``<robot>/<device>``).
        per_amp: joint torque per motor ampere (``messages.torque_per_amp``).
        node: the live ROS 2 node, or None. decimation: its joint-state/IMU rate divisor.
        files: the MCAP episodes, or None.
    """

    def __init__(self, robot: str, per_amp: np.ndarray, node: Ros2Node | None = None, decimation: int = 1,
                 files: McapEpisodes | None = None) -> None:
        self.robot, self.per_amp, self.node, self.decimation, self.files = robot, per_amp, node, decimation, files
        self._per_amp = tuple(float(k) for k in per_amp)  # the fast path multiplies floats
        self._episode: _Episode | None = None
        self.published = 0

    def _put(self, topic: str, msg: object, stamp_ns: int, live: bool = True) -> None:
        self._put_cdr(topic, m.serialize(msg, m.TOPICS[topic]), stamp_ns, live)

    def _put_cdr(self, topic: str, data: bytes, stamp_ns: int, live: bool = True) -> None:
        if live and self.node is not None:
            self.node.put(topic, data)
            self.published += 1
        if self.files is not None:
            self.files.write(topic, data, stamp_ns)

    def _log(self, stamp_ns: int, level: int, text: str) -> None:
        if self.files is not None:
            self.files.log(stamp_ns, level, text)

    def begin(self, request: EpisodeRequest, start_ns: int, period_ns: int) -> None:
        self._episode = _Episode(request, start_ns, period_ns)
        if self.files is not None:
            self.files.begin(request.episode_id, start_ns)
        self._log(start_ns, m.LOG_INFO, f"episode {request.episode_id} started: {request.task} "
                  f"theta={list(request.theta)} seed={request.seed}")
        self._put("episode", m.episode_status(self.robot, request, None), start_ns)

    def emcy(self, events: list[EmcyEvent]) -> None:
        """EMCY frames the bus heard: published with the next cycle (or the end)."""
        if self._episode is not None:
            self._episode.emcy.extend(events)

    def frames(self, timestamp: float, frames: list, sent: bool) -> None:
        if self._episode is not None and self.files is not None:
            self.files.frames(timestamp, frames, sent)

    def cycle(self, tel: Telemetry) -> None:
        ep = self._episode
        if ep is None:
            return
        stamp = ep.stamp(tel.cycle)
        live = self.node is not None and ep.index % self.decimation == 0
        if live or self.files is not None:
            self._put_cdr("joint_states", m.joint_state_cdr(tel, stamp, self._per_amp), stamp, live)
            self._put_cdr("imu", m.imu_cdr(tel, stamp), stamp, live)
        statuses = []
        if tel.status != ep.status or ep.index - ep.last_diagnostics >= DIAGNOSTICS_EVERY:
            statuses += m.device_statuses(self.robot, tel)
            ep.status = tel.status
        statuses += self._emcy_statuses(ep, stamp)
        if statuses:
            ep.last_diagnostics = ep.index
            self._put("diagnostics", m.diagnostics(stamp, statuses), stamp)
        ep.index += 1

    def _emcy_statuses(self, ep: _Episode, stamp: int) -> list:
        statuses = []
        for ev in ep.emcy:
            statuses.append(m.emcy_status(self.robot, ev))
            self._log(stamp, m.LOG_INFO if ev.code == 0 else m.LOG_WARN,
                      statuses[-1].message + f" (register 0x{ev.register:02X})")
        ep.emcy = []
        return statuses

    def end(self, result: EpisodeResult | None, fault: str, end_ns: int, dropped: int) -> None:
        """The episode's end (``dropped``: its cycles and frame bursts the agent's queue dropped)."""
        ep, self._episode = self._episode, None
        if ep is None:
            return
        stamp = max(end_ns, ep.stamp(ep.first_cycle or 0) + ep.index * ep.period_ns)
        statuses = self._emcy_statuses(ep, stamp)
        if result is not None and not result.ok:
            statuses.append(m.fault_status(self.robot, result))
        if statuses:
            self._put("diagnostics", m.diagnostics(stamp, statuses), stamp)
        if result is not None:
            self._put("episode", m.episode_status(self.robot, ep.request, result, fault), stamp)
        status = result.status if result is not None else fault or "failed"
        self._log(stamp, m.LOG_INFO if result is not None and result.ok else m.LOG_ERROR,
                  f"episode {ep.request.episode_id} ended: {status}"
                  + (f" ({result.detail})" if result is not None and result.detail else "")
                  + (f", cost {result.total_cost:.6g}" if result is not None and result.total_cost is not None else ""))
        if self.files is not None:
            self.files.end(dropped)

    def close(self) -> None:
        """The input ended: an episode still open is not whole (``McapEpisodes.close``)."""
        self._episode = None
        if self.files is not None:
            self.files.close()
