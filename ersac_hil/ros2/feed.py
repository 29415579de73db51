"""What the agent's hooks feed: a bounded queue and one thread, and the MCAP writer process.

``observe(tel)`` (the ``EpisodeRunner`` hook, on the SYNC loop's thread) and ``frames`` (the
agent bus's tap, ``AgentBus.tap``: the frames it sends and receives) only append to a bounded
queue, without a lock and without waking anyone (the thread looks every ``POLL_S``); when the
queue is full the item is dropped and counted (``dropped``; per episode in the MCAP file's
metadata and a warning), so the control loop never waits for ROS 2 or the disk. The thread
turns samples into ROS 2 messages (``messages``) for the live node (``bridge.Ros2Node``, every
``decimation``-th cycle), handing the interpreter on after every item (a SYNC loop waiting for
it would otherwise wait up to Python's switch interval, 5 ms), and hands everything of an
episode, in batches, to the MCAP writer process (``writer.RecorderProcess``), which encodes what is not encoded yet and writes
the file. ``begin``/``end`` frame an episode; ``end`` returns the file's name at once (the file
appears under it when complete, ``recorder``).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from ersac_hil.agent.bus import EmcyEvent
from ersac_hil.agent.telemetry import Telemetry
from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.bridge import Ros2Node
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.ros2.writer import CLOSE_WAIT_S, RecorderProcess
from protocol.robot import RobotDescription
from protocol.zenoh import EpisodeRequest, EpisodeResult

log = logging.getLogger(__name__)

DIAGNOSTICS_EVERY = 200
"""Cycles between two diagnostics when nothing changed (1 s at 200 Hz)."""
BATCH = 512
"""Records handed to the writer process at a time."""
POLL_S = 0.002
"""How often the thread looks for new items during an episode."""


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
    dropped0: int = 0

    def stamp(self, cycle: int) -> int:
        """The robot's time of a cycle: the episode's start plus SYNC periods."""
        if self.first_cycle is None:
            self.first_cycle = cycle
        return self.start_ns + (cycle - self.first_cycle) * self.period_ns


class Feed:
    """``start()``, the hooks ``observe`` and ``frames``, per episode ``begin`` ... ``end``, ``stop()``.

    Args:
        robot: the robot's name (diagnostic names ``<robot>/<device>``).
        node: the live ROS 2 node, or None. decimation: its joint-state/IMU rate divisor.
        recorder: the MCAP writer process, or None.
        emcy: ``since -> EMCY events from there`` (the agent bus's log), or None.
        queue_size: items (cycles, frame bursts) the thread may lag behind.
        description: the robot description (joint efforts from its torque constants and
            gears; None: the default description).
    """

    def __init__(self, robot: str, node: Ros2Node | None = None, decimation: int = 1,
                 recorder: RecorderProcess | None = None,
                 emcy: Callable[[int], list[EmcyEvent]] | None = None, queue_size: int = 16384,
                 description: RobotDescription | None = None) -> None:
        self.robot, self.node, self.decimation, self.recorder = robot, node, decimation, recorder
        self._emcy = emcy
        self._items: deque = deque()
        self._capacity = queue_size
        self._wake = threading.Event()
        self._drop_lock = threading.Lock()  # drops are counted from the SYNC loop's and the bus's threads
        self._thread: threading.Thread | None = None
        self._episode: _Episode | None = None
        self._batch: list = []
        self._per_amp = m.torque_per_amp(description)
        self._framing = False  # between begin and end: the tap's frames are queued
        self._request: EpisodeRequest | None = None
        self.dropped = 0
        self.published = 0

    @classmethod
    def for_agent(cls, config, session, bus) -> "Feed":  # noqa: ANN001 - AgentConfig, zenoh.Session, AgentBus
        """The feed of an agent service: its ROS 2 node (``config.ros2``) and MCAP files
        (``config.record``, with the frames of the agent's own bus), started."""
        options = config.ros2 or Ros2Options()
        node = Ros2Node.declare(session, options, config.robot) if config.ros2 is not None else None
        recorder = None
        if config.record is not None:
            recorder = RecorderProcess(config.record, options.namespace_for(config.robot), config.robot,
                                       m.torque_per_amp(config.description).tolist())
        feed = cls(config.robot, node, options.decimation, recorder, bus.emcy_events, options.queue_size,
                   config.description).start()
        if recorder is not None:
            bus.tap(feed.frames)
        return feed

    def start(self) -> "Feed":
        self._thread = threading.Thread(target=self._run, name="ros2-feed", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Drain the queue, end the writer process (it finishes every file it was sent), withdraw
        the node."""
        self._framing = False
        thread = self._thread
        if thread is not None:
            self._control(None)
            thread.join(timeout=CLOSE_WAIT_S)
            if thread.is_alive() and self.recorder is not None:
                # it waits on the full pipe to a writer far behind: end the writer, the write fails
                log.warning("MCAP writer process %.0f s behind at stop: ended", CLOSE_WAIT_S)
                self.recorder.terminate()
                thread.join(timeout=CLOSE_WAIT_S)
            self._thread = None
        if self.recorder is not None:
            self.recorder.close()  # at most CLOSE_WAIT_S more, then the writer is ended
            self.recorder = None
        if self.node is not None:
            self.node.close()

    # -- the control loop's and the bus's side (never blocks) ---------------------------------
    def _offer(self, item: tuple) -> None:
        if len(self._items) < self._capacity:
            self._items.append(item)
        else:
            with self._drop_lock:
                self.dropped += 1

    def observe(self, tel: Telemetry) -> None:
        self._offer(("cycle", tel))

    def frames(self, timestamp: float, frames: list, sent: bool) -> None:
        """The agent bus's tap (``AgentBus.tap``): frames go to the episode's file."""
        if self._framing:
            self._offer(("frames", timestamp, frames, sent))

    def _control(self, item: tuple | None) -> None:
        """Begin, end, stop: never dropped, and the thread is woken for them."""
        self._items.append(item)
        self._wake.set()

    # -- the agent service's side -------------------------------------------------------------
    def begin(self, request: EpisodeRequest, period_s: float, emcy_mark: int = 0) -> None:
        self._request = request
        self._control(("begin", request, time.time_ns(), round(period_s * 1e9), emcy_mark, self.dropped))
        self._framing = self.recorder is not None

    def end(self, result: EpisodeResult | None, fault: str = "") -> str:
        """Close the episode; the name its MCAP file will have (``""`` without recording)."""
        self._framing = False
        self._control(("end", result, fault))
        recorder, request, self._request = self.recorder, self._request, None
        return f"{request.episode_id}.mcap" if recorder is not None and recorder.alive and request else ""

    # -- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        items = self._items
        while True:
            self._wake.wait(POLL_S if self._episode is not None else None)
            self._wake.clear()
            while items:
                item = items.popleft()
                if item is None:
                    self._send()
                    return
                try:
                    getattr(self, "_on_" + item[0])(*item[1:])
                except Exception as exc:  # never let one bad sample stop the thread
                    log.exception("ROS 2 feed: %s", exc)
                time.sleep(0)  # let a waiting SYNC loop or receive thread have the interpreter

    def _record(self, *record: object) -> None:
        if self.recorder is not None:
            self._batch.append(record)
            if len(self._batch) >= BATCH:
                self._send()

    def _send(self) -> None:
        if self._batch and self.recorder is not None:
            self.recorder.send(self._batch)
        self._batch = []

    def _put(self, topic: str, msg: object, stamp_ns: int) -> None:
        data = m.serialize(msg, m.TOPICS[topic])
        if self.node is not None:
            self.node.put(topic, data)
            self.published += 1
        self._record("msg", topic, data, stamp_ns)

    def _log(self, stamp_ns: int, level: int, text: str) -> None:
        self._record("log", stamp_ns, level, text)

    def _on_begin(self, request: EpisodeRequest, start_ns: int, period_ns: int, emcy_mark: int,
                  dropped: int) -> None:
        self._episode = _Episode(request, start_ns, period_ns, emcy_seen=emcy_mark, dropped0=dropped)
        self._record("begin", request.episode_id, start_ns)
        self._log(start_ns, m.LOG_INFO, f"episode {request.episode_id} started: {request.task} "
                  f"theta={list(request.theta)} seed={request.seed}")
        self._put("episode", m.episode_status(self.robot, request, None), start_ns)

    def _on_frames(self, timestamp: float, frames: list, sent: bool) -> None:
        if self._episode is not None:
            self._record("frames", timestamp, frames, sent)

    def _on_cycle(self, tel: Telemetry) -> None:
        ep = self._episode
        if ep is None:
            return
        stamp = ep.stamp(tel.cycle)
        if self.node is not None and ep.index % self.decimation == 0:
            for topic, msg in (("joint_states", m.joint_state(tel, stamp, self._per_amp)), ("imu", m.imu(tel, stamp))):
                data = m.serialize(msg, m.TOPICS[topic])
                self.node.put(topic, data)
                self.published += 1
                self._record("msg", topic, data, stamp)
        else:  # the file's alone: the writer process encodes it
            self._record("tel", stamp, tel)
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

    def _on_end(self, result: EpisodeResult | None, fault: str) -> None:
        ep = self._episode
        if ep is None:
            return
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
        dropped = self.dropped - ep.dropped0
        if dropped:
            log.warning("ROS 2 feed: %d samples or frame bursts of episode %s dropped (the feed fell a "
                        "whole queue behind); the MCAP file's metadata 'feed' says so", dropped, ep.request.episode_id)
        self._record("end", dropped)
        self._send()
        self._episode = None
