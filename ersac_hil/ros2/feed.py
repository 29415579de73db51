"""What the agent's hooks feed: a bounded queue, handed on as it is to the feed process
(``writer``), which does everything else.

``observe(tel)`` (the ``EpisodeRunner`` hook, on the SYNC loop's thread) and ``frames`` (the
agent bus's tap, ``AgentBus.tap``: every frame it sends and receives) only append to a bounded
queue, without a lock and without waking anyone; when the queue is full the item is dropped
and counted (``dropped``; per episode in the MCAP file's metadata and a warning), so the control
loop never waits for ROS 2 or the disk. The items (the cycle's ``Telemetry``, the frame bursts,
the bus's new EMCY events) go unchanged, in batches, down the pipe of the feed process, which
makes the ROS 2 messages, publishes them as the agent's ROS 2 node and writes the MCAP files:
no ROS 2 serialization, no Zenoh put and no file in the agent's interpreter.

Who hands them on: during an episode, the SYNC loop itself (``pump``, the agent bus's
``while_waiting``), right after each SYNC is sent, while the nodes answer it: each cycle what
the last one queued, with a write that never waits (``FeedProcess.try_send``). In lock-step
the simulator computes then, so the hand-off takes little from the episode's wall time, where
a thread of its own, woken beside the loop, took the interpreter from it (lock-step with the
bridge and recording, side by side: 2.91 s against the thread's 3.19 s, and 2.5 % below
off; batches of a few cycles from the loop cost more wall time again, though they halve the
feed process's CPU: ``bench/episode.py``, docs/ros2.md). The feed's thread does the rest:
begin/end and stop, a pipe that was full (it may wait on it, the loop never does), and what a
loop that stopped cycling left (it looks every ``POLL_S`` during an episode). One of them at a
time, in queue order. ``begin``/``end`` frame an episode; ``end`` returns the file's name at
once (the file appears under it when complete, ``recorder``).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from ersac_hil.agent.bus import EmcyEvent
from ersac_hil.agent.telemetry import Telemetry
from ersac_hil.ros2.options import PART, Ros2Options
from ersac_hil.ros2.writer import CLOSE_WAIT_S, TERM_WAIT_S, FeedProcess, FeedSettings
from ersac_hil.zenoh_session import ZenohOptions
from protocol.zenoh import EpisodeRequest, EpisodeResult

log = logging.getLogger(__name__)

BATCH = 32
"""Items the thread hands to the feed process in one pickle at most."""
PUMP_MAX = 128
"""Items the SYNC loop hands on at once at most (one pickle of ~60 us)."""
POLL_S = 0.1
"""How often the thread looks for items the SYNC loop left during an episode (a loop that
stopped cycling: a fault, a long wait)."""
CONTROL = ("begin", "end")
"""Items only the thread hands on (it keeps the episode's state)."""


class Feed:
    """``start()``, the hooks ``observe`` and ``frames``, per episode ``begin`` ... ``end``, ``stop()``.

    Args:
        process: the feed process (``writer.FeedProcess``).
        emcy: ``since -> EMCY events from there`` (the agent bus's log), or None.
        queue_size: items (cycles, frame bursts) the thread may lag behind.
        record: the MCAP directory (files are named by ``end``), or None.
    """

    def __init__(self, process: FeedProcess, emcy: Callable[[int], list[EmcyEvent]] | None = None,
                 queue_size: int = 16384, record: str | Path | None = None) -> None:
        self.process = process
        self._emcy = emcy
        self._emcy_seen = 0
        self.record = Path(record) if record is not None else None
        self._items: deque = deque()
        self._capacity = queue_size
        self._wake = threading.Event()
        self._consumer = threading.Lock()  # held by whoever hands items on: one at a time, in order
        self._drop_lock = threading.Lock()  # drops are counted from the SYNC loop's and the bus's threads
        self._thread: threading.Thread | None = None
        self._framing = False  # between begin and end: the tap's frames are queued
        self._in_episode = False  # the thread's view
        self._dropped0 = 0
        self._episode_id = ""
        self._request: EpisodeRequest | None = None
        self._unconfirmed: list[str] = []  # files named by end() not yet seen under their names
        self.dropped = 0

    @classmethod
    def for_agent(cls, config, bus) -> "Feed":  # noqa: ANN001 - AgentConfig, AgentBus
        """The feed of an agent service: its ROS 2 node (``config.ros2``, on a session of the
        agent's Zenoh configuration) and MCAP files (``config.record``, with every frame of the
        agent's own bus), started."""
        options = config.ros2 or Ros2Options()
        settings = FeedSettings(config.robot, options.namespace_for(config.robot), config.description,
                                config.record, config.ros2,
                                ZenohOptions(config.zenoh_connect, config.zenoh_config, config.zenoh_insecure),
                                config.zenoh_mode)
        process = FeedProcess(settings)
        if config.ros2 is not None:
            log.info("ROS 2 node %s/%s on domain %d, published by the feed process (pid %d)",
                     settings.namespace.rstrip("/"), options.node, options.domain, process.pid)
        feed = cls(process, bus.emcy_events, options.queue_size, config.record).start()
        if config.record is not None:
            bus.tap(feed.frames)
        bus.while_waiting = feed.pump
        return feed

    def start(self) -> "Feed":
        self._thread = threading.Thread(target=self._run, name="ros2-feed", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Hand on what is queued and end the feed process: it finishes every file it was
        sent and withdraws the node, within ``CLOSE_WAIT_S`` in all; then it is ended, and
        a file it had not finished stays ``.part`` (a warning names it)."""
        self._framing = False
        deadline = time.monotonic() + CLOSE_WAIT_S
        thread = self._thread
        if thread is not None:
            self._control(None)
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
            if thread.is_alive():  # it waits on the full pipe to a child far behind
                self.process.end_now()  # the write fails, the thread hands on nothing more
                thread.join(timeout=TERM_WAIT_S)
            self._thread = None
        status = self.process.close(deadline)
        record = self.record
        unfinished = [n for n in self._unconfirmed if not (record / n).is_file()] if record is not None else []
        if unfinished:
            log.warning("MCAP files not finished within %.0f s of the agent's stop (the feed process, at "
                        "niceness +10, was behind; exit status %s): %s", CLOSE_WAIT_S, status,
                        ", ".join(n + PART + " left" if (record / (n + PART)).is_file() else n + " never begun"
                                  for n in unfinished))
        self._unconfirmed = []

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

    def pump(self) -> None:
        """Hand on what is queued (the last cycle's telemetry and frames), from the SYNC loop
        while the nodes answer its SYNC (the agent bus's ``while_waiting``); never waits: nothing is done while the thread hands on (or waits
        on a full pipe), nor beyond a control item, and a batch the pipe has no room for goes
        back to the queue's head, for the thread (woken)."""
        items = self._items
        if not items or not self._consumer.acquire(blocking=False):
            return
        try:
            batch = []
            while items and len(batch) < PUMP_MAX:
                head = items[0]
                if head is None or head[0] in CONTROL:
                    break
                batch.append(items.popleft())
            batch += self._new_emcy()
            if batch and not self.process.try_send(batch):
                items.extendleft(reversed(batch))  # producers only append: the order stays
                self._wake.set()
            elif self.process.unsent:  # the pipe took part of the batch: the thread writes the rest
                self._wake.set()
        finally:
            self._consumer.release()

    def _control(self, item: tuple | None) -> None:
        """Begin, end, stop: never dropped, and the thread is woken for them."""
        self._items.append(item)
        self._wake.set()

    # -- the agent service's side -------------------------------------------------------------
    def begin(self, request: EpisodeRequest, period_s: float, emcy_mark: int = 0) -> None:
        self._request = request
        self._control(("begin", request, time.time_ns(), round(period_s * 1e9), emcy_mark, self.dropped))
        self._framing = self.record is not None

    def end(self, result: EpisodeResult | None, fault: str = "") -> str:
        """Close the episode; the name its MCAP file will have (``""`` without recording)."""
        self._framing = False
        self._control(("end", result, fault, time.time_ns()))
        request, self._request = self._request, None
        if self.record is None or not self.process.alive or request is None:
            return ""
        name = f"{request.episode_id}.mcap"
        self._unconfirmed = [n for n in self._unconfirmed if not (self.record / n).is_file()] + [name]
        return name

    # -- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            self._wake.wait(POLL_S if self._in_episode else None)
            self._wake.clear()
            with self._consumer:
                if not self._hand_on():
                    return

    def _hand_on(self) -> bool:
        """Everything queued to the feed process (holding ``_consumer``); False at the stop."""
        items, batch = self._items, []
        while items:
            item = items.popleft()
            if item is None:
                self._send(batch)
                return False
            if item[0] == "begin":
                item = self._on_begin(*item[1:])
            elif item[0] == "end":
                batch += self._new_emcy()
                item = self._on_end(*item[1:])
            batch.append(item)
            if len(batch) >= BATCH:
                batch = self._send(batch)
        self._send(batch + self._new_emcy())
        return True

    def _send(self, batch: list) -> list:
        if batch or self.process.unsent:  # unsent: the tail of a batch the SYNC loop began
            self.process.send(batch)
            time.sleep(0)  # let a waiting SYNC loop or receive thread have the interpreter
        return []

    def _new_emcy(self) -> list:
        if not self._in_episode or self._emcy is None:
            return []
        events = self._emcy(self._emcy_seen)
        self._emcy_seen += len(events)
        return [("emcy", events)] if events else []

    def _on_begin(self, request: EpisodeRequest, start_ns: int, period_ns: int, emcy_mark: int,
                  dropped: int) -> tuple:
        self._in_episode, self._emcy_seen, self._dropped0 = True, emcy_mark, dropped
        self._episode_id = request.episode_id
        return ("begin", request, start_ns, period_ns)

    def _on_end(self, result: EpisodeResult | None, fault: str, end_ns: int) -> tuple:
        self._in_episode = False
        dropped = self.dropped - self._dropped0
        if dropped:
            log.warning("ROS 2 feed: %d samples or frame bursts of episode %s dropped (the feed fell a "
                        "whole queue behind); the MCAP file's metadata 'feed' says so", dropped, self._episode_id)
        return ("end", result, fault, end_ns, dropped)
