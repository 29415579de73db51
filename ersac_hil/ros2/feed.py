"""What the agent's cycle hook feeds: a bounded queue and one publisher thread.

``observe(tel)`` (the ``EpisodeRunner`` hook, on the SYNC loop's thread) only puts the sample
into the queue; when the queue is full the sample is dropped and counted (``dropped``), so
the control loop never waits for ROS 2 or the disk. The thread turns samples into ROS 2
messages (``messages``) once and hands them to the live node (``bridge.Ros2Node``, every
``decimation``-th cycle) and to the episode's MCAP file (``recorder``, every cycle). What only
the file needs (the cycles not published live, the CAN frames) is encoded after the episode's
last cycle, so that the control loop shares the interpreter with as little as possible.
``begin``/``end`` frame an episode (``end`` waits until the thread has written everything of
it and returns the MCAP file name).
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field

from ersac_hil.agent.bus import EmcyEvent
from ersac_hil.agent.telemetry import Telemetry
from ersac_hil.agent.trace import CanRecorder
from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.bridge import Ros2Node
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.ros2.recorder import FrameTap, McapEpisodes
from protocol.robot import RobotDescription
from protocol.zenoh import EpisodeRequest, EpisodeResult

log = logging.getLogger(__name__)

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
    emcy_seen: int = 0
    records: list = field(default_factory=list)  # (topic, CDR or a sample to encode, stamp) for the file

    def stamp(self, cycle: int) -> int:
        """The robot's time of a cycle: the episode's start plus SYNC periods."""
        if self.first_cycle is None:
            self.first_cycle = cycle
        return self.start_ns + (cycle - self.first_cycle) * self.period_ns


class Feed:
    """``start()``, the hook ``observe``, per episode ``begin`` ... ``end``, ``stop()``.

    Args:
        robot: the robot's name (diagnostic names ``<robot>/<device>``).
        node: the live ROS 2 node, or None. decimation: its joint-state/IMU rate divisor.
        recorder: the MCAP episodes, or None.
        emcy: ``since -> EMCY events from there`` (the agent bus's log), or None.
        queue_size: samples the thread may lag behind.
        tap: a CAN trace tap whose frames go into the MCAP files, or None.
        description: the robot description (joint efforts from its torque constants and
            gears; None: the default description).
    """

    def __init__(self, robot: str, node: Ros2Node | None = None, decimation: int = 1,
                 recorder: McapEpisodes | None = None,
                 emcy: Callable[[int], list[EmcyEvent]] | None = None, queue_size: int = 16384,
                 tap: CanRecorder | None = None, description: RobotDescription | None = None) -> None:
        self.robot, self.node, self.decimation, self.recorder = robot, node, decimation, recorder
        self.tap = tap
        self._emcy = emcy
        self._queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None
        self._episode: _Episode | None = None
        self._per_amp = m.torque_per_amp(description)
        self.dropped = 0
        self._dropped0 = 0
        self.published = 0

    @classmethod
    def for_agent(cls, config, session, bus) -> "Feed":  # noqa: ANN001 - AgentConfig, zenoh.Session, AgentBus
        """The feed of an agent service: its ROS 2 node (``config.ros2``) and MCAP files
        (``config.record``, with a CAN tap on the agent's bus), started."""
        options = config.ros2 or Ros2Options()
        node = Ros2Node.declare(session, options, config.robot) if config.ros2 is not None else None
        recorder = tap = None
        if config.record is not None:
            recorder = McapEpisodes(config.record, options.namespace_for(config.robot), config.robot)
            tap = CanRecorder(config.bus, config.record).start()
        return cls(config.robot, node, options.decimation, recorder, bus.emcy_events,
                   options.queue_size, tap, config.description).start()

    def start(self) -> "Feed":
        self._thread = threading.Thread(target=self._run, name="ros2-feed", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=30.0)
            self._thread = None
        if self.tap is not None:
            self.tap.stop()
        if self.recorder is not None:
            self.recorder.close()
        if self.node is not None:
            self.node.close()

    # -- the control loop's side (never blocks) ---------------------------------------------
    def observe(self, tel: Telemetry) -> None:
        try:
            self._queue.put_nowait(("cycle", tel))
        except queue.Full:
            self.dropped += 1

    # -- the agent service's side -------------------------------------------------------------
    def begin(self, request: EpisodeRequest, period_s: float, emcy_mark: int = 0) -> None:
        start_ns = time.time_ns()
        if self.recorder is not None:  # open before the tap hands it frames
            self.recorder.begin(request.episode_id, start_ns)
            self._dropped0 = self.dropped
        if self.tap is not None:
            self.tap.begin(request.episode_id, writer=FrameTap(self.recorder))
        self._queue.put(("begin", request, start_ns, round(period_s * 1e9), emcy_mark))

    def end(self, result: EpisodeResult | None, fault: str = "") -> str:
        """Finish the episode's messages; the MCAP file name (``""`` if none)."""
        if self.tap is not None:
            self.tap.end()
        done: Future = Future()
        self._queue.put(("end", result, fault, done))
        return done.result(timeout=60.0)

    # -- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                getattr(self, "_on_" + item[0])(*item[1:])
            except Exception as exc:  # never let one bad sample stop the thread
                log.exception("ROS 2 feed: %s", exc)
                if item[0] == "end" and not item[-1].done():
                    item[-1].set_result("")

    def _put(self, topic: str, msg: object, stamp_ns: int, live: bool = True) -> None:
        data = m.serialize(msg, m.TOPICS[topic])
        if live and self.node is not None:
            self.node.put(topic, data)
            self.published += 1
        if self.recorder is not None:
            if self._episode is not None:
                self._episode.records.append((topic, data, stamp_ns))
            else:
                self.recorder.write(topic, data, stamp_ns)

    def _log(self, stamp_ns: int, level: int, text: str) -> None:
        if self.recorder is not None and self._episode is not None:
            self._episode.records.append(("events", (level, text), stamp_ns))

    def _flush(self, ep: _Episode) -> None:
        """The episode's file: every record in order, encoding what was left for later."""
        rec = self.recorder
        for topic, data, stamp in ep.records:
            if topic == "events":
                rec.log(stamp, *data)  # type: ignore[union-attr]
                continue
            if isinstance(data, Telemetry):
                data = m.serialize(m.joint_state(data, stamp, self._per_amp) if topic == "joint_states"
                                   else m.imu(data, stamp), m.TOPICS[topic])
            rec.write(topic, data, stamp)  # type: ignore[union-attr]
        ep.records = []

    def _on_begin(self, request: EpisodeRequest, start_ns: int, period_ns: int, emcy_mark: int) -> None:
        self._episode = _Episode(request, start_ns, period_ns, emcy_seen=emcy_mark)
        self._log(start_ns, m.LOG_INFO, f"episode {request.episode_id} started: {request.task} "
                  f"theta={list(request.theta)} seed={request.seed}")
        self._put("episode", m.episode_status(self.robot, request, None), start_ns)

    def _on_cycle(self, tel: Telemetry) -> None:
        ep = self._episode
        if ep is None:
            return
        stamp = ep.stamp(tel.cycle)
        live = ep.index % self.decimation == 0
        if live and self.node is not None:
            self._put("joint_states", m.joint_state(tel, stamp, self._per_amp), stamp)
            self._put("imu", m.imu(tel, stamp), stamp)
        elif self.recorder is not None:  # the file's alone: encoded after the episode
            ep.records += [("joint_states", tel, stamp), ("imu", tel, stamp)]
        statuses = []
        if tel.status != ep.status or ep.index - ep.last_diagnostics >= DIAGNOSTICS_EVERY:
            statuses += m.device_statuses(self.robot, tel)
            ep.status = tel.status
        if self._emcy is not None:
            for ev in self._emcy(ep.emcy_seen):
                ep.emcy_seen += 1
                statuses.append(m.emcy_status(self.robot, ev))
                self._log(stamp, m.LOG_INFO if ev.code == 0 else m.LOG_WARN,
                          statuses[-1].message + f" (register 0x{ev.register:02X})")
        if statuses:
            ep.last_diagnostics = ep.index
            self._put("diagnostics", m.diagnostics(stamp, statuses), stamp)
        ep.index += 1

    def _on_end(self, result: EpisodeResult | None, fault: str, done: Future) -> None:
        ep, name = self._episode, ""
        if ep is not None:
            stamp = max(time.time_ns(), ep.stamp(ep.first_cycle or 0) + ep.index * ep.period_ns)
            if result is not None:
                if not result.ok:
                    self._put("diagnostics", m.diagnostics(stamp, [m.fault_status(self.robot, result)]), stamp)
                self._put("episode", m.episode_status(self.robot, ep.request, result, fault), stamp)
            status = result.status if result is not None else fault or "failed"
            self._log(stamp, m.LOG_INFO if result is not None and result.ok else m.LOG_ERROR,
                      f"episode {ep.request.episode_id} ended: {status}"
                      + (f" ({result.detail})" if result is not None and result.detail else "")
                      + (f", cost {result.total_cost:.6g}" if result is not None and result.total_cost is not None else ""))
            if self.recorder is not None:
                self._flush(ep)
                name = self.recorder.end(dropped=self.dropped - self._dropped0)
        self._episode = None
        done.set_result(name)
