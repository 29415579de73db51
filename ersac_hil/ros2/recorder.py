"""Each episode as one MCAP file (``agent --record DIR`` -> ``DIR/<episode_id>.mcap``), ROS 2
profile: CDR messages with their ``ros2msg`` schemas, the topics of ``messages.TOPICS`` (every
cycle, no decimation) under the robot's namespace, the CAN frames of the episode on ``<ns>/can``
(``can_msgs/msg/Frame``) and its events on ``<ns>/events`` (``foxglove_msgs/msg/Log``).
Foxglove, PlotJuggler, the ``mcap`` CLI, rosbags and ``ros2 bag`` open them. Log and publish
times are the messages' stamps [ns since the epoch].

A file is written as ``<episode_id>.mcap.part`` and renamed to ``<episode_id>.mcap`` when it is
complete, so a file under its name is always whole. This runs in the feed process
(``writer``), never in the agent's.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType, Writer

from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.options import PART

LIBRARY = "ersac-hil"
COMPRESSION = CompressionType.LZ4
"""Chunk compression: LZ4 costs the writer about a quarter less per message than zstd (MCAP's
default), and every MCAP reader named above reads both."""


class McapEpisodes:
    """``begin(episode_id, start_ns)``, ``write``/``log``/``frames``, ``end() -> name``.

    Args:
        directory: where the files go (created). namespace: the robot's ROS namespace.
        robot: the name in the events' ``name`` field.
    """

    def __init__(self, directory: str | Path, namespace: str, robot: str) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.prefix = namespace.rstrip("/")
        self.robot = robot
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._name = ""

    def begin(self, episode_id: str, start_ns: int) -> None:
        self.end()
        name = f"{episode_id}.mcap"
        self._file = open(self.directory / (name + PART), "wb")
        self._writer = Writer(self._file, compression=COMPRESSION)
        self._writer.start(profile="ros2", library=LIBRARY)
        self._channels, self._sequence, self._name = {}, {}, name
        for topic, typename in {**m.TOPICS, **m.RECORDED}.items():
            schema = self._writer.register_schema(typename, "ros2msg", m.msgdef(typename).encode())
            self._channels[topic] = self._writer.register_channel(f"{self.prefix}/{topic}", "cdr", schema)
            self._sequence[topic] = 0
        self._writer.add_metadata("episode", {"episode_id": episode_id, "robot": self.robot,
                                              "start_ns": str(start_ns)})

    def write(self, topic: str, data: bytes, stamp_ns: int) -> None:
        if self._writer is None:
            return
        self._sequence[topic] += 1
        self._writer.add_message(self._channels[topic], stamp_ns, data, stamp_ns, self._sequence[topic])

    def log(self, stamp_ns: int, level: int, text: str) -> None:
        self.write("events", m.serialize(m.log(stamp_ns, level, text, self.robot), m.LOG), stamp_ns)

    def frames(self, timestamp_s: float, frames: list, sent: bool) -> None:
        """CAN frames of one burst (``AgentBus.tap``), sent or received: ``(COB-ID, data)``
        pairs (standard data frames) or ``(id, flags, dlc, data)``, all stamped ``timestamp_s``."""
        stamp = round(timestamp_s * 1e9)
        for frame in frames:
            if len(frame) == 2:
                cdr = m.can_frame_cdr(stamp, frame[0], 0, len(frame[1]), frame[1])
            else:
                cdr = m.can_frame_cdr(stamp, *frame)
            self.write("can", cdr, stamp)

    def end(self, dropped: int = 0, whole: bool = True) -> str:
        """Finish the episode's file and (``whole``) give it its name; the name (``""`` if none
        was open). Not ``whole``: readable, but cut short, so it keeps the ``.part`` suffix."""
        if self._writer is None:
            return ""
        self._writer.add_metadata("feed", {"dropped_samples": str(dropped), "whole": str(whole).lower()})
        self._writer.finish()
        self._file.close()  # type: ignore[union-attr]
        if whole:
            os.replace(self.directory / (self._name + PART), self.directory / self._name)
        name, self._writer, self._file, self._name = self._name, None, None, ""
        return name

    def close(self) -> None:
        """Finish what is open: an episode whose end never came is not whole (``end``)."""
        self.end(whole=False)
