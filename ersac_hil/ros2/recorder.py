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
import struct
from itertools import accumulate
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex, Statistics
from mcap.writer import CompressionType, Writer

try:  # the writer's private chunk builder (mcap 1.x), for the fast path (``_Messages``)
    from mcap._chunk_builder import ChunkBuilder
except ImportError:  # another mcap: its Writer.add_message
    ChunkBuilder = None

from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.options import PART

LIBRARY = "ersac-hil"
COMPRESSION = CompressionType.LZ4
"""Chunk compression: LZ4 costs the writer about a quarter less per message than zstd (MCAP's
default), and every MCAP reader named above reads both."""
CHUNK_SIZE = 1024 * 1024
"""MCAP chunk size before compression (the ``mcap`` writer's default)."""


_MESSAGE = struct.Struct("<BQHIQQ")
"""An MCAP Message record's opcode, length, channel id, sequence, log and publish time."""
_INDEX = struct.Struct("<BQHI")
"""An MCAP Message Index record's opcode, length, channel id and byte length of its entries."""


class _PackedIndex(MessageIndex):
    """A chunk's message index of one channel, written as ``MessageIndex.write`` writes it, in
    two packs instead of two calls per entry."""

    def write(self, stream: Any) -> None:
        n = 16 * len(self.records)
        stream.write(_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + n, self.channel_id, n))
        if self.records:
            stream.write(np.array(self.records, dtype="<u8").tobytes())


class _Messages:
    """Messages into an ``mcap`` ``Writer``'s open chunk, as its ``add_message`` puts them there
    (the same record, message index entry and statistics; a chunk is finished at the same
    message), a burst of messages of one channel and one time at a time, at a pack a message
    instead of some 30 Python calls: an episode has ~20 messages a SYNC cycle, most of them CAN
    frames. It uses the writer's private state (mcap 1.x); ``of(writer)`` is None where that is
    not what it expects, and the writer's own ``add_message`` is used. A test holds the files
    byte for byte equal to those of ``add_message``."""

    def __init__(self, writer: Writer) -> None:
        self._chunks: ChunkBuilder = writer._Writer__chunk_builder  # type: ignore[attr-defined]
        self._stats: Statistics = writer._Writer__statistics  # type: ignore[attr-defined]
        self._chunk_size: int = writer._Writer__chunk_size  # type: ignore[attr-defined]
        self._add = writer.add_message

    @classmethod
    def of(cls, writer: Writer) -> "_Messages | None":
        try:
            self = cls(writer)
            chunks = self._chunks
            ok = (ChunkBuilder is not None and type(chunks) is ChunkBuilder and isinstance(chunks.message_indices, dict)
                  and isinstance(chunks.record_writer.count, int) and isinstance(self._chunk_size, int)
                  and type(self._stats) is Statistics and isinstance(self._stats.message_count, int))
        except AttributeError:
            return None
        return self if ok else None

    def add(self, channel_id: int, stamp_ns: int, sequence: int, datas: list) -> None:
        """``datas`` on ``channel_id``, all logged and published at ``stamp_ns``, sequence
        numbers from ``sequence`` on."""
        chunks = self._chunks
        start, pack = chunks.record_writer.count, _MESSAGE.pack
        records = [pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence + i, stamp_ns, stamp_ns) + data
                   for i, data in enumerate(datas)]
        entries = [(stamp_ns, at) for at in accumulate(map(len, records), initial=start)]
        if not records or entries.pop()[1] > self._chunk_size:  # the chunk ends within: as the writer does it
            for i, data in enumerate(datas):
                self._add(channel_id, stamp_ns, data, stamp_ns, sequence + i)
            return
        chunks.record_writer.write(b"".join(records))
        if chunks.num_messages == 0:
            chunks.message_start_time = stamp_ns
        else:
            chunks.message_start_time = min(chunks.message_start_time, stamp_ns)
        chunks.message_end_time = max(chunks.message_end_time, stamp_ns)
        index = chunks.message_indices.get(channel_id)
        if type(index) is not _PackedIndex:
            index = chunks.message_indices[channel_id] = _PackedIndex(channel_id, index.records if index else [])
        index.records += entries
        chunks.num_messages += len(entries)
        stats = self._stats
        if stats.message_count == 0:
            stats.message_start_time = stamp_ns
        else:
            stats.message_start_time = min(stamp_ns, stats.message_start_time)
        stats.message_end_time = max(stamp_ns, stats.message_end_time)
        stats.channel_message_counts[channel_id] += len(entries)
        stats.message_count += len(entries)


class McapEpisodes:
    """``begin(episode_id, start_ns)``, ``write``/``log``/``frames``, ``end() -> name``.

    Args:
        directory: where the files go (created). namespace: the robot's ROS namespace.
        robot: the name in the events' ``name`` field.
        chunk_size: the MCAP chunks' size before compression [bytes] (``Writer``'s).
        fast: messages straight into the chunks (``_Messages``); False: by ``Writer.add_message``.
    """

    def __init__(self, directory: str | Path, namespace: str, robot: str, chunk_size: int = CHUNK_SIZE,
                 fast: bool = True) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.prefix = namespace.rstrip("/")
        self.robot = robot
        self.chunk_size, self.fast = chunk_size, fast
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._messages: _Messages | None = None
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._name = ""

    def begin(self, episode_id: str, start_ns: int) -> None:
        self.end()
        name = f"{episode_id}.mcap"
        self._file = open(self.directory / (name + PART), "wb")
        self._writer = Writer(self._file, chunk_size=self.chunk_size, compression=COMPRESSION)
        self._messages = _Messages.of(self._writer) if self.fast else None
        self._writer.start(profile="ros2", library=LIBRARY)
        self._channels, self._sequence, self._name = {}, {}, name
        for topic, typename in {**m.TOPICS, **m.RECORDED}.items():
            schema = self._writer.register_schema(typename, "ros2msg", m.msgdef(typename).encode())
            self._channels[topic] = self._writer.register_channel(f"{self.prefix}/{topic}", "cdr", schema)
            self._sequence[topic] = 0
        self._writer.add_metadata("episode", {"episode_id": episode_id, "robot": self.robot,
                                              "start_ns": str(start_ns)})

    def write(self, topic: str, data: bytes, stamp_ns: int) -> None:
        self._write(topic, stamp_ns, [data])

    def _write(self, topic: str, stamp_ns: int, datas: list) -> None:
        if self._writer is None:
            return
        sequence = self._sequence[topic] + 1
        self._sequence[topic] += len(datas)
        if self._messages is not None:
            self._messages.add(self._channels[topic], stamp_ns, sequence, datas)
            return
        for i, data in enumerate(datas):
            self._writer.add_message(self._channels[topic], stamp_ns, data, stamp_ns, sequence + i)

    def log(self, stamp_ns: int, level: int, text: str) -> None:
        self.write("events", m.serialize(m.log(stamp_ns, level, text, self.robot), m.LOG), stamp_ns)

    def frames(self, timestamp_s: float, frames: list, sent: bool) -> None:
        """CAN frames of one burst (``AgentBus.tap``), sent or received: ``(COB-ID, data)``
        pairs (standard data frames) or ``(id, flags, dlc, data)``, all stamped ``timestamp_s``."""
        stamp = round(timestamp_s * 1e9)
        self._write("can", stamp, m.can_frames_cdr(stamp, frames))

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
        self._messages = None
        return name

    def close(self) -> None:
        """Finish what is open: an episode whose end never came is not whole (``end``)."""
        self.end(whole=False)
