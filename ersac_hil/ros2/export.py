"""``ersac-hil report RUN --mcap FILE [--mcap-dir DIR]``: a run in one MCAP file (ROS 2 profile).

From the store: every attempt as ``<ns>/episode`` (the agent's per-episode message,
``messages.episode_status``; attempts the agent never answered carry the daemon's status)
and every learner update as ``<ns>/learner/updates`` (``messages.update_status``), stamped
when they were recorded. With ``--mcap-dir`` (the agent's ``--record`` directory), every
message of each episode's own MCAP file too, on its own topics. ``<ns>`` is ``/<robot>``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

from ersac_hil.daemon.store import EpisodeRecord, Store
from ersac_hil.ros2 import messages as m
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.ros2.recorder import LIBRARY
from protocol.zenoh import STATUSES, EpisodeRequest, EpisodeResult


@dataclass(frozen=True)
class Export:
    """What an export holds: attempts, updates, episode files copied, files named but missing."""
    path: Path
    attempts: int
    updates: int
    episode_files: int
    missing: tuple[str, ...]


def _result(record: EpisodeRecord, task: str) -> EpisodeResult | None:
    if record.status not in STATUSES or record.cost_terms is None:
        return None
    return EpisodeResult(record.episode_id, task, record.status, dict(record.cost_terms), record.agent_cost,
                         dict(record.failures or {}), record.duration_s or 0.0, record.wall_s or 0.0,
                         dict(record.telemetry or {}), dict(record.fault_counts or {}), record.detail,
                         record.trace, record.mcap)


class _Out:
    """One MCAP writer with schemas and channels registered once by (name, text) / topic."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}

    def channel(self, topic: str, typename: str, encoding: str = "ros2msg", data: bytes | None = None) -> int:
        if topic not in self._channels:
            data = data if data is not None else m.msgdef(typename).encode()
            key = (typename, encoding, data)
            if key not in self._schemas:
                self._schemas[key] = self.writer.register_schema(typename, encoding, data)
            self._channels[topic] = self.writer.register_channel(topic, "cdr", self._schemas[key])
        return self._channels[topic]

    def add(self, channel: int, stamp_ns: int, data: bytes) -> None:
        self._seq[channel] = self._seq.get(channel, 0) + 1
        self.writer.add_message(channel, stamp_ns, data, stamp_ns, self._seq[channel])


def export_run(db: str | Path, run_id: str, out: str | Path, mcap_dir: str | Path | None = None) -> Export:
    """Write ``run_id`` of the store ``db`` into the MCAP file ``out``.

    Raises:
        StoreError / RunNotFound: no such store or run.
    """
    with Store(db, readonly=True) as store:
        run = store.run(run_id)
        attempts, updates = store.attempts(run_id), store.updates(run_id)
    ns = Ros2Options().namespace_for(run.robot).rstrip("/")
    path, copied, missing = Path(out), 0, []
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library=LIBRARY)
        writer.add_metadata("run", {"run_id": run.run_id, "robot": run.robot, "task": run.task,
                                    "seed": str(run.seed)})
        o = _Out(writer)
        episodes, learner = o.channel(f"{ns}/episode", m.STATUS), o.channel(f"{ns}/{m.UPDATES}", m.STATUS)
        for record in attempts:
            request = EpisodeRequest(record.episode_id, run.task, record.theta, record.seed)
            result = _result(record, run.task)
            msg = m.episode_status(run.robot, request, result, "" if result is not None else record.status)
            o.add(episodes, round((record.finished_s or record.requested_s) * 1e9), m.serialize(msg, m.STATUS))
            if mcap_dir is not None and record.mcap:
                source = Path(mcap_dir) / record.mcap
                if not source.is_file():
                    missing.append(record.mcap)
                    continue
                with open(source, "rb") as src:
                    for schema, channel, message in make_reader(src).iter_messages():
                        cid = o.channel(channel.topic, schema.name, schema.encoding, schema.data)
                        o.add(cid, message.log_time, message.data)
                copied += 1
        for update in updates:
            o.add(learner, round(update.stamp_s * 1e9), m.serialize(m.update_status(run.robot, update), m.STATUS))
        writer.finish()
    return Export(path, len(attempts), len(updates), copied, tuple(missing))
