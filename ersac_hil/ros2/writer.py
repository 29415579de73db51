"""The MCAP writer process of ``agent --record DIR``: the episodes' files are encoded and
written by a child process of the agent, so that none of it shares the agent's interpreter
(and its lock) with the SYNC loop.

The agent (``RecorderProcess``, from the feed's thread) sends batches of records down the
child's stdin, each a length-prefixed pickle of a list of tuples:

* ``("open", directory, namespace, robot, torque_per_amp)`` (first, once);
* ``("begin", episode_id, start_ns)``, ``("end", dropped_samples)``;
* ``("msg", topic, cdr, stamp_ns)``: a message already in CDR;
* ``("tel", stamp_ns, telemetry)``: one cycle's ``Telemetry`` (its joint state and IMU);
* ``("log", stamp_ns, level, text)``: an event;
* ``("frames", timestamp_s, frames, sent)``: CAN frames of one burst (``AgentBus.tap``).

The child runs at a lower priority: normal scheduling (a real-time agent's SCHED_FIFO, which
children inherit, is dropped) at niceness ``NICE``, so when the cores are busy the control
loop and the simulator go first and the writer catches up later (its input is the pipe, enlarged to
``PIPE_BYTES``, behind the feed's bounded queue). The child ignores SIGINT (a Ctrl-C reaches the whole process group; the agent then closes the
pipe) and ends at the end of its input: it finishes the episode it has open and exits, so the
agent's ``close`` leaves no child. On SIGTERM (``close`` after ``CLOSE_WAIT_S``) it stops at
once. Either way a file it has not seen the end of is finished as far as it got but stays
``.part``: a file under its name is always whole.
"""
from __future__ import annotations

import fcntl
import logging
import os
import pickle
import signal
import struct
import subprocess
import sys
from typing import BinaryIO

log = logging.getLogger(__name__)

_LENGTH = struct.Struct("<I")
NICE = 10
"""The writer process's niceness above the agent's."""
PIPE_BYTES = 1 << 20
"""The pipe to the writer (Linux ``F_SETPIPE_SZ``, where allowed; else the system's default)."""
CLOSE_WAIT_S = 5.0
"""How long ``close`` waits for the child to write what it was sent before it ends it (the
episode it was writing then stays ``<episode_id>.mcap.part``): an agent stops within seconds."""


class RecorderProcess:
    """The agent's side: ``send(records) -> bool`` (False once the child is gone), ``close()``."""

    def __init__(self, directory: str, namespace: str, robot: str, torque_per_amp: list[float]) -> None:
        self._proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.ros2.writer"], stdin=subprocess.PIPE)
        try:
            fcntl.fcntl(self._proc.stdin, getattr(fcntl, "F_SETPIPE_SZ", 1031), PIPE_BYTES)  # type: ignore[arg-type]
        except OSError:  # above /proc/sys/fs/pipe-max-size: the default stays
            pass
        self.alive = True
        self.send([("open", str(directory), namespace, robot, list(torque_per_amp))])

    def send(self, records: list) -> bool:
        if not self.alive:
            return False
        data = pickle.dumps(records, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            self._proc.stdin.write(_LENGTH.pack(len(data)) + data)  # type: ignore[union-attr]
            self._proc.stdin.flush()  # type: ignore[union-attr]
        except (OSError, ValueError) as exc:  # BrokenPipeError: the child is gone
            self.alive = False
            log.error("MCAP writer process gone (%s, status %s): recording stopped", exc, self._proc.poll())
            return False
        return True

    def terminate(self) -> None:
        """End the child now (SIGTERM): a write waiting on the full pipe fails at once."""
        if self._proc.poll() is None:
            self._proc.terminate()

    def close(self, timeout_s: float = CLOSE_WAIT_S) -> int:
        """End the child's input and wait until it has written everything; its exit status."""
        try:
            self._proc.stdin.close()  # type: ignore[union-attr]
        except OSError:
            pass
        try:
            return self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            log.warning("MCAP writer process still writing after %.0f s: ended, its last episode's file "
                        "stays <episode_id>.mcap.part", timeout_s)
            self._proc.terminate()
            try:
                return self._proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                return self._proc.wait()


def _read(stream: BinaryIO, n: int) -> bytes | None:
    data = b""
    while len(data) < n:
        chunk = stream.read(n - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def serve(stream: BinaryIO) -> None:
    """Apply every batch of ``stream`` until its end (the child's main loop)."""
    from ersac_hil.ros2 import messages as m
    from ersac_hil.ros2.recorder import McapEpisodes

    episodes: McapEpisodes | None = None
    per_amp = None
    try:
        while (head := _read(stream, _LENGTH.size)) is not None:
            body = _read(stream, _LENGTH.unpack(head)[0])
            if body is None:
                break
            for record in pickle.loads(body):
                kind = record[0]
                if kind == "tel":
                    _, stamp, tel = record
                    episodes.write("joint_states", m.serialize(m.joint_state(tel, stamp, per_amp), m.JOINT_STATE), stamp)  # type: ignore[union-attr]
                    episodes.write("imu", m.serialize(m.imu(tel, stamp), m.IMU), stamp)  # type: ignore[union-attr]
                elif kind == "frames":
                    episodes.frames(*record[1:])  # type: ignore[union-attr]
                elif kind == "msg":
                    episodes.write(*record[1:])  # type: ignore[union-attr]
                elif kind == "log":
                    episodes.log(*record[1:])  # type: ignore[union-attr]
                elif kind == "begin":
                    episodes.begin(*record[1:])  # type: ignore[union-attr]
                elif kind == "end":
                    episodes.end(*record[1:])  # type: ignore[union-attr]
                elif kind == "open":
                    import numpy as np
                    _, directory, namespace, robot, amps = record
                    episodes, per_amp = McapEpisodes(directory, namespace, robot), np.array(amps, dtype=np.float64)
    finally:
        if episodes is not None:
            episodes.close()  # an episode still open (its end never came) stays .part


def _background() -> None:
    """This process off real-time scheduling (inherited from a real-time agent), ``NICE`` lower."""
    if hasattr(os, "sched_setscheduler"):
        try:
            if os.sched_getscheduler(0) != os.SCHED_OTHER:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except OSError as exc:  # lowering is always permitted; say so if it was not
            log.warning("MCAP writer process keeps its scheduling: %s", exc)
    os.nice(NICE)


def main() -> int:
    _background()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    try:
        serve(sys.stdin.buffer)
    except Exception as exc:  # noqa: BLE001 - one line, then the agent sees the pipe break
        log.error("MCAP writer process failed: %s", exc)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
