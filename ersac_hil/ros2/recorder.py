"""Each episode as one MCAP file (``agent --record DIR`` -> ``DIR/<episode_id>.mcap``), ROS 2
profile: CDR messages with their ``ros2msg`` schemas, the topics of ``messages.TOPICS`` (every
cycle, no decimation) under the robot's namespace, every CAN frame of the episode on
``<ns>/can`` (``can_msgs/msg/Frame``) and its events on ``<ns>/events``
(``foxglove_msgs/msg/Log``). Foxglove, PlotJuggler, the ``mcap`` CLI, rosbags and ``ros2 bag``
open them. Log and publish times are the messages' stamps [ns since the epoch]."""
from __future__ import annotations

import threading
from pathlib import Path
from typing import IO

import can
from mcap.writer import Writer

from ersac_hil.ros2 import messages as m

LIBRARY = "ersac-hil"


class McapEpisodes:
    """``begin(episode_id, start_ns)``, ``write``/``log``/``frame`` (thread-safe), ``end() -> name``.

    Args:
        directory: where the files go (created). namespace: the robot's ROS namespace.
        robot: the name in the events' ``name`` field.
    """

    def __init__(self, directory: str | Path, namespace: str, robot: str) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.prefix = namespace.rstrip("/")
        self.robot = robot
        self._lock = threading.Lock()
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._name = ""
        self._frames: list[tuple] = []

    def begin(self, episode_id: str, start_ns: int) -> None:
        self.end()
        name = f"{episode_id}.mcap"
        with self._lock:
            self._file = open(self.directory / name, "wb")
            self._writer = Writer(self._file)
            self._writer.start(profile="ros2", library=LIBRARY)
            self._channels, self._sequence, self._name, self._frames = {}, {}, name, []
            for topic, typename in {**m.TOPICS, **m.RECORDED}.items():
                schema = self._writer.register_schema(typename, "ros2msg", m.msgdef(typename).encode())
                self._channels[topic] = self._writer.register_channel(f"{self.prefix}/{topic}", "cdr", schema)
                self._sequence[topic] = 0
            self._writer.add_metadata("episode", {"episode_id": episode_id, "robot": self.robot,
                                                  "start_ns": str(start_ns)})

    def write(self, topic: str, data: bytes, stamp_ns: int) -> None:
        with self._lock:
            if self._writer is None:
                return
            self._sequence[topic] += 1
            self._writer.add_message(self._channels[topic], stamp_ns, data, stamp_ns, self._sequence[topic])

    def log(self, stamp_ns: int, level: int, text: str) -> None:
        self.write("events", m.serialize(m.log(stamp_ns, level, text, self.robot), m.LOG), stamp_ns)

    def frame(self, msg: can.Message) -> None:
        """One CAN frame (the trace tap's thread): kept as it is, encoded when the episode ends
        (a dozen frames per cycle would otherwise take the control loop's interpreter)."""
        with self._lock:
            if self._writer is not None:
                self._frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_extended_id,
                                     msg.is_remote_frame, msg.is_error_frame))

    def _write_frames(self) -> None:
        frames, self._frames = self._frames, []
        for frame in frames:
            self._sequence["can"] += 1
            stamp = round(frame[0] * 1e9)
            self._writer.add_message(self._channels["can"], stamp, m.serialize(m.can_frame(*frame), m.CAN_FRAME),  # type: ignore[union-attr]
                                     stamp, self._sequence["can"])

    def end(self, dropped: int = 0) -> str:
        """Close the episode's file; its name (``""`` if none was open)."""
        with self._lock:
            if self._writer is None:
                return ""
            self._write_frames()
            self._writer.add_metadata("feed", {"dropped_samples": str(dropped)})
            self._writer.finish()
            self._file.close()  # type: ignore[union-attr]
            name, self._writer, self._file, self._name = self._name, None, None, ""
            return name

    def close(self) -> None:
        self.end()


class FrameTap(can.Listener):
    """The CAN trace tap's writer for an MCAP episode (``CanRecorder.begin(..., writer=)``)."""

    def __init__(self, episodes: McapEpisodes) -> None:
        self.episodes = episodes

    def on_message_received(self, msg: can.Message) -> None:
        self.episodes.frame(msg)

    def stop(self) -> None:
        pass
