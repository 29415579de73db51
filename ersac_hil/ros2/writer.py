"""The feed process of ``agent --ros2`` / ``--record DIR``: a child process of the agent makes
the ROS 2 messages (rosbags' CDR), publishes them on its own Zenoh session as the agent's ROS 2
node (``bridge``), and writes the episodes' MCAP files (``recorder``), so that none of it shares
the agent's interpreter (and its lock) with the SYNC loop. It opens its session with the
agent's Zenoh configuration (the same endpoints, the same certificate: the same identity to
the router's access control), listening nowhere.

The agent (``FeedProcess``, from the SYNC loop's thread while the nodes answer, or from the
feed's thread) sends batches of records down the child's
stdin, each a length-prefixed pickle of a list of tuples, the first one ``("open",
FeedSettings)``; then the records of ``stream.EpisodeStream`` as the agent had them:

* ``("begin", request, start_ns, period_ns)``, ``("end", result, fault, end_ns, dropped)``;
* ``("cycle", telemetry)``, ``("emcy", [EmcyEvent, ...])``;
* ``("frames", timestamp_s, frames, sent)``: CAN frames of one burst (``AgentBus.tap``).

The child says ``ready`` on its stdout once its node is declared, its files can be written and
what each message type costs once is done (``messages.warm_up``; ``FeedProcess`` waits for
it, so the agent announces itself only with its ROS 2 node up) or exits with a one-line error.

The child runs at a lower priority: normal scheduling (a real-time agent's SCHED_FIFO, which
children inherit, is dropped) at niceness ``NICE``, so when the cores are busy the control
loop and the simulator go first and the child catches up later (its input is the pipe,
enlarged to ``PIPE_BYTES``, behind the feed's bounded queue). The child ignores SIGINT and
SIGTERM (a Ctrl-C or a supervisor's SIGTERM reaches the whole process group; the agent then
hands on what it has queued and closes the pipe) and ends at the end of its input: it
finishes the episode it has open, withdraws its node and exits, so the agent's ``close``
leaves no child, and a dead agent's child ends too (its pipe closes). On ``STOP_NOW``
(SIGUSR1, ``FeedProcess.end_now`` at the agent's deadline) it stops at once, and a
SIGKILL follows ``TERM_WAIT_S`` later. A file it has not seen the end of is finished as far
as it got (or, killed, cut off) but stays ``.part``: a file under its name is always whole.
"""
from __future__ import annotations

import fcntl
import logging
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import BinaryIO

from ersac_hil.ros2.options import Ros2Options
from ersac_hil.zenoh_session import ZenohOptions
from protocol.robot import RobotDescription

log = logging.getLogger(__name__)

_LENGTH = struct.Struct("<I")
NICE = 10
"""The feed process's niceness above the agent's."""
PIPE_BYTES = 1 << 20
"""The pipe to the child (Linux ``F_SETPIPE_SZ``, where allowed; else the system's default)."""
CLOSE_WAIT_S = 5.0
"""How long an agent's stop gives the child, in all, to finish what it was sent before it is
ended (the episode it was writing then stays ``<episode_id>.mcap.part``)."""
TERM_WAIT_S = 1.0
"""After ``STOP_NOW``, how long the child may take before SIGKILL."""
STOP_NOW = signal.SIGUSR1
"""The agent's "stop at once" (SIGINT and SIGTERM reach the whole group: the child ignores them)."""
READY_WAIT_S = 60.0
"""How long the agent waits for the child's ``ready`` (imports and a Zenoh session, on a loaded
machine)."""
READY = b"ready\n"
FAILURES_SAID = 3
"""Failed records the child logs (with their traceback); it goes on with the next."""


class FeedProcessError(RuntimeError):
    """The feed process did not start (its own error line is on the agent's stderr)."""


@dataclass(frozen=True)
class FeedSettings:
    """What the child needs: the robot, where the files go, whether and how it publishes.

    Attributes:
        robot: the robot's name. namespace: its ROS namespace (topics, MCAP channels).
        description: the robot description (joint efforts), None: the default one.
        record: the MCAP directory (``--record``), or None.
        ros2: the ROS 2 node's options (``--ros2``), or None: no live node.
        zenoh, zenoh_mode: the agent's Zenoh session configuration (with ``ros2``).
    """
    robot: str
    namespace: str
    description: RobotDescription | None = None
    record: str | None = None
    ros2: Ros2Options | None = None
    zenoh: ZenohOptions = ZenohOptions()
    zenoh_mode: str = "client"


class FeedProcess:
    """The agent's side: ``send(records) -> bool`` (False once the child is gone),
    ``close(deadline)``. Starting waits for the child's ``ready`` (``FeedProcessError``)."""

    def __init__(self, settings: FeedSettings, ready_wait_s: float = READY_WAIT_S) -> None:
        self._proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.ros2.writer"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE)
        try:
            fcntl.fcntl(self._proc.stdin, getattr(fcntl, "F_SETPIPE_SZ", 1031), PIPE_BYTES)  # type: ignore[arg-type]
        except OSError:  # above /proc/sys/fs/pipe-max-size: the default stays
            pass
        try:  # the same pipe, a file description of its own that never waits (try_send)
            self._nonblocking: int | None = os.open(f"/proc/self/fd/{self._proc.stdin.fileno()}",  # type: ignore[union-attr]
                                                    os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:  # no /proc: try_send never writes, send does
            self._nonblocking = None
        self._unsent = b""  # the tail of what try_send began: it goes first, with the next send
        self.alive = True
        self.send([("open", settings)])
        try:
            self._wait_ready(ready_wait_s)
        except FeedProcessError:
            self.alive = False
            self.end_now()
            self._close_nonblocking()
            raise

    @property
    def pid(self) -> int:
        return self._proc.pid

    def _wait_ready(self, timeout_s: float) -> None:
        out = self._proc.stdout
        assert out is not None
        ready, _, _ = select.select([out], [], [], timeout_s)
        line = out.readline() if ready else b""
        out.close()
        if line != READY:
            why = "it ended, see its error above" if ready else f"no answer within {timeout_s:.0f} s"
            raise FeedProcessError(f"the ROS 2/MCAP feed process did not start ({why})")

    def send(self, records: list) -> bool:
        """Hand ``records`` on (after what ``try_send`` left unsent), waiting while the pipe
        is full; False once the child is gone."""
        if not self.alive:
            return False
        data, self._unsent = self._unsent + (self._framed(records) if records else b""), b""
        return self._write(data) if data else True

    @property
    def unsent(self) -> bool:
        """``try_send`` wrote part of a batch: the next ``send`` (which may wait) writes the rest."""
        return bool(self._unsent)

    def try_send(self, records: list) -> bool:
        """Hand ``records`` on without ever waiting (the SYNC loop's hand-off,
        ``feed.Feed.pump``): a non-blocking write on the pipe. False leaves them unsent: the
        pipe is full (the child is behind), a part of an earlier batch is still unsent, no
        non-blocking write is possible, or the child is gone. True when the pipe took them,
        possibly only in part (``unsent``: the rest is for the next ``send``). Must not run
        beside another ``send``/``try_send`` (the feed's one consumer at a time)."""
        if not self.alive or self._unsent or self._nonblocking is None:
            return False
        data = self._framed(records)
        try:
            n = os.write(self._nonblocking, data)
        except BlockingIOError:
            return False
        except OSError as exc:  # BrokenPipeError: the child is gone
            self._gone(exc)
            return False
        self._unsent = data[n:]
        return True

    @staticmethod
    def _framed(records: list) -> bytes:
        data = pickle.dumps(records, protocol=pickle.HIGHEST_PROTOCOL)
        return _LENGTH.pack(len(data)) + data

    def _write(self, data: bytes) -> bool:
        try:
            self._proc.stdin.write(data)  # type: ignore[union-attr]
            self._proc.stdin.flush()  # type: ignore[union-attr]
        except (OSError, ValueError) as exc:  # BrokenPipeError: the child is gone
            self._gone(exc)
            return False
        return True

    def _close_nonblocking(self) -> None:
        fd, self._nonblocking = self._nonblocking, None
        if fd is not None:
            os.close(fd)

    def _gone(self, exc: Exception) -> None:
        self.alive = False
        log.error("ROS 2/MCAP feed process gone (%s, status %s): publishing and recording stopped",
                  exc, self._proc.poll())

    def end_now(self) -> int:
        """End the child now: ``STOP_NOW`` (it finishes its open file as far as it got,
        ``.part``), SIGKILL after ``TERM_WAIT_S`` (a child starved of CPU or stopped cannot act
        on a signal it handles); a write waiting on the full pipe then fails at once. Its exit
        status."""
        if self._proc.poll() is None:
            self._proc.send_signal(STOP_NOW)
            try:
                return self._proc.wait(TERM_WAIT_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        return self._proc.wait()

    def close(self, deadline: float) -> int:
        """End the child's input and wait until it has done everything, at the latest until
        ``deadline`` (``time.monotonic()``), then ``end_now``; its exit status. Never returns
        with the child alive, nor later than ``TERM_WAIT_S`` after ``deadline``."""
        self.alive = False
        try:
            self._proc.stdin.close()  # type: ignore[union-attr]
        except OSError:  # the child is gone: what was buffered cannot be flushed
            pass
        self._close_nonblocking()  # the input ends when the last writing end is closed
        try:
            return self._proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            return self.end_now()


def _read(stream: BinaryIO, n: int) -> bytes | None:
    data = b""
    while len(data) < n:
        chunk = stream.read(n - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def _batches(stream: BinaryIO):  # noqa: ANN202 - Iterator[list]
    while (head := _read(stream, _LENGTH.size)) is not None:
        body = _read(stream, _LENGTH.unpack(head)[0])
        if body is None:
            return
        yield pickle.loads(body)


def serve(stream: BinaryIO, ready: BinaryIO | None = None) -> None:
    """Open what ``("open", settings)`` asks for, say ``READY`` on ``ready``, then apply every
    record of ``stream`` until its end (the child's main loop)."""
    from ersac_hil.ros2 import messages as m
    from ersac_hil.ros2.bridge import Ros2Node
    from ersac_hil.ros2.recorder import McapEpisodes
    from ersac_hil.ros2.stream import EpisodeStream

    batches = _batches(stream)
    first = next(batches, None)
    if not first or first[0][0] != "open":
        raise ValueError("the feed's input does not start with its settings")
    settings: FeedSettings = first[0][1]
    session = node = None
    episodes: EpisodeStream | None = None
    try:
        files = McapEpisodes(settings.record, settings.namespace, settings.robot) if settings.record else None
        if settings.ros2 is not None:
            from ersac_hil.zenoh_session import open_session, resolve_config, tolerate_bursts
            # live topics drop like rmw_zenoh's (DROP), but not the bursts of a feed catching up
            config = tolerate_bursts(resolve_config(settings.zenoh, mode=settings.zenoh_mode))
            config.insert_json5("listen/endpoints", "[]")  # the agent listens where it was told to
            session = open_session(config, insecure=settings.zenoh.insecure)
            node = Ros2Node.declare(session, settings.ros2, settings.robot)
        episodes = EpisodeStream(settings.robot, m.torque_per_amp(settings.description), node,
                                 settings.ros2.decimation if settings.ros2 is not None else 1, files)
        m.warm_up()
        if ready is not None:
            ready.write(READY)
            ready.close()
        failed = 0
        for batch in batches:
            for record in batch:
                try:
                    getattr(episodes, record[0])(*record[1:])
                except Exception as exc:  # never let one bad record stop the feed; say the first few
                    failed += 1
                    if failed <= FAILURES_SAID:
                        log.exception("ROS 2/MCAP feed: a %r record failed: %s", record[0], exc)
    finally:
        if episodes is not None:
            episodes.close()  # an episode still open (its end never came) stays .part
        if node is not None:
            node.close()
        if session is not None:
            session.close()


def _background() -> None:
    """This process off real-time scheduling (inherited from a real-time agent), ``NICE`` lower."""
    if hasattr(os, "sched_setscheduler"):
        try:
            if os.sched_getscheduler(0) != os.SCHED_OTHER:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except OSError as exc:  # lowering is always permitted; say so if it was not
            log.warning("ROS 2/MCAP feed process keeps its scheduling: %s", exc)
    os.nice(NICE)


def _stop_now(*_: object) -> None:
    """``STOP_NOW``: leave at once (``serve``'s ``finally`` closes what is open); once only, so
    that a repeated signal does not cut that short."""
    signal.signal(STOP_NOW, signal.SIG_IGN)
    sys.exit(0)


def main() -> int:
    _background()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(STOP_NOW, _stop_now)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    ready = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed goes to the agent's stderr, not into the pipe it stops reading
    try:
        serve(sys.stdin.buffer, ready)
    except Exception as exc:  # noqa: BLE001 - one line, then the agent sees the pipe break
        log.error("ROS 2/MCAP feed process failed: %s", exc)
        return 1
    return 0


def _exit(code: object) -> None:
    """Leave without the interpreter's finalization: the files are closed and the session and
    node are gone by now (``serve``'s ``finally``), and tearing down the modules (zenoh, numpy,
    mcap, rosbags) took ~0.09 of the ~0.1 s of CPU the child spent after its input ended -
    seconds of wall time for a child at niceness +10 on a busy machine, past the agent's
    ``CLOSE_WAIT_S``, where ``STOP_NOW`` then met the default handler finalization restores
    (exit -SIGUSR1). As ``multiprocessing`` ends its children."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code if isinstance(code, int) else 0 if code is None else 1)


if __name__ == "__main__":
    status: object = 1
    try:
        try:
            status = main()
        finally:  # from here on STOP_NOW changes nothing (it may come at any moment, even now)
            signal.signal(STOP_NOW, signal.SIG_IGN)
    except SystemExit as stop:  # STOP_NOW's handler
        status = stop.code
    _exit(status)
