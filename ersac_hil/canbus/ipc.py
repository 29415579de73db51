"""CAN over a Unix-domain socket: a python-can interface plugin (``interface="ipc"``) for
simulated benches, where agent and simulator run on one computer.

One bus listens on a socket path, the others connect to it; every frame one bus sends reaches
every other bus of the path, in the order its sender sent them (the listener relays between
the connected buses, like ``ersac_hil.canbus.direct``'s listening bus does for CAN over
Zenoh)::

    can.Bus(interface="ipc", channel="/run/ersac-hil/can0.sock", listen=True)   # the simulator
    can.Bus(interface="ipc", channel="/run/ersac-hil/can0.sock")                # the agent

The socket is ``SOCK_SEQPACKET``: reliable, in order, message boundaries kept, so one message
is one burst of frames in CAN over Zenoh's wire form (``ersac_hil.canbus.frames``), and it
needs nothing between the two processes but the kernel: a send is one system call on the
sending thread, a receive one on the bus's receive thread, which hands the frames straight to
the push listeners (:meth:`PushingBus.push_notifier`, canopen's networks through
``protocol.can.busconfig.open_network``). Measured on this project's 2-core virtual machine (load
average ~13), a bare 200 Hz request/answer between two processes under ``SCHED_FIFO`` took a
median 0.13 ms a round trip this way against 0.80 ms through Zenoh's Python binding on a direct
link; whole real-time cycles: docs/performance.md, "Real time at 200 Hz".

Who may use the bus is who may open the path: the listener creates its socket with mode 0600
(its own user only) and refuses a path where another bus still listens; a socket file left by
a listener that died is replaced. It never leaves the computer, so it is for simulated robots
only; a robot's bus is ``socketcan``. A bus does not hear its own frames unless
``receive_own_messages=True`` (then on the sending thread, after the send). Delivery is
reliable and blocking, as CAN over Zenoh's congestion control ``BLOCK``: a connected bus that
stops reading holds the sends to it up once its socket's buffer is full. While the listener
is away (a simulator restarting), the connected buses' sends fail (``can.CanOperationError``,
what a CAN controller reports when no node acknowledges) and they keep connecting again: the
frames flow once a listener is back on the path.
"""
from __future__ import annotations

import errno
import logging
import os
import selectors
import socket
import stat
import threading
import time
from typing import Any

import can
from can.bus import CanProtocol

from ersac_hil.canbus.frames import MessageSender, PushingBus, flag_arg, seconds_arg
from protocol.can.fastpath import FramePusher

__all__ = ["IpcBus", "MAX_MESSAGE", "path_of"]

MAX_MESSAGE = 65536
"""Bytes of one message (one burst); a larger send is refused."""
_PATH_MAX = 107  # sun_path holds 108 bytes with the terminating NUL
_CONNECT_RETRY_S = 0.02
_RECONNECT_S = 0.05
_log = logging.getLogger(__name__)


def path_of(channel: Any) -> str:
    """The socket path a channel names.

    Raises:
        ValueError: not a non-empty string, a NUL byte in it, or longer than a socket path may be.
    """
    if not isinstance(channel, str) or not channel:
        raise ValueError(f"ipc CAN channel must be a socket path, got {channel!r}")
    if "\0" in channel:
        raise ValueError("ipc CAN channel: a socket path has no NUL byte")
    if len(os.fsencode(channel)) > _PATH_MAX:
        raise ValueError(f"ipc CAN channel {channel!r}: longer than a Unix socket path may be ({_PATH_MAX} bytes)")
    return channel


class IpcBus(MessageSender, PushingBus, FramePusher):
    """A python-can bus on a Unix-domain socket (see the module doc).

    Args:
        channel: the socket path.
        listen: this bus creates the socket and relays between the buses that connect to it
            (``True``/``False`` or python-can configuration's strings).
        receive_own_messages: also receive the frames this bus sends.
        connect_timeout: s a connecting bus keeps trying while nobody listens yet.
        **kwargs: other python-can arguments (``bitrate``, ``can_filters``...); bit rate has
            no meaning here and is ignored.

    Raises:
        can.CanInitializationError: a bad path, another bus listening there, nobody listening.
    """

    def __init__(self, channel: Any = None, can_filters=None, *, listen: bool | str = False,  # noqa: ANN001
                 receive_own_messages: bool | str = False, connect_timeout: float | str = 10.0,
                 **kwargs: Any) -> None:
        try:
            self.path = path_of(channel)
            self.listening = flag_arg(listen, "listen")
            self._own = flag_arg(receive_own_messages, "receive_own_messages")
            timeout = seconds_arg(connect_timeout, "connect_timeout")
        except ValueError as exc:
            raise can.CanInitializationError(str(exc)) from None
        self.channel_info = f"CAN over the Unix socket {self.path}" + (" (listening)" if self.listening else "")
        self._name = self.path
        self._send_lock = threading.Lock()
        self._closed = False
        self._peers: list[socket.socket] = []  # listening: the connected buses; else the listener
        self._wake: tuple[socket.socket, socket.socket] | None = None
        self._inode: tuple[int, int] | None = None
        self._server: socket.socket | None = None
        self._start_receiving()
        if self.listening:
            self._server = self._bind(self.path)
            self._wake = socket.socketpair()
        else:
            self._peers.append(self._connect(self.path, timeout))
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD
        target = self._relay if self.listening else self._receive
        self._receiver = threading.Thread(target=target, name=f"ipc-can-rx {self.path}", daemon=True)
        self._receiver.start()

    # -- opening -------------------------------------------------------------------------------
    def _bind(self, path: str) -> socket.socket:
        self._replace_stale(path)
        server = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            server.bind(path)
            os.chmod(path, 0o600)  # before listen(): nobody else can connect in between
            info = os.stat(path)
            self._inode = (info.st_dev, info.st_ino)
            server.listen(16)
        except OSError as exc:
            server.close()
            raise can.CanInitializationError(f"{self.channel_info}: cannot listen: {exc.strerror or exc}") from None
        return server

    def _replace_stale(self, path: str) -> None:
        """A socket file nobody listens on any more goes; a live one or another file stays."""
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            return
        except OSError as exc:
            raise can.CanInitializationError(f"{self.channel_info}: {exc.strerror or exc}") from None
        if not stat.S_ISSOCK(info.st_mode):
            raise can.CanInitializationError(f"{self.channel_info}: {path} exists and is not a socket")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            probe.connect(path)
        except (ConnectionRefusedError, FileNotFoundError):
            os.unlink(path)  # its listener is gone
            return
        except OSError as exc:
            raise can.CanInitializationError(f"{self.channel_info}: {exc.strerror or exc}") from None
        finally:
            probe.close()
        raise can.CanInitializationError(f"{self.channel_info}: another bus already listens on {path}")

    def _connect(self, path: str, timeout: float) -> socket.socket:
        deadline = time.monotonic() + timeout
        while True:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            try:
                sock.connect(path)
                return sock
            except (FileNotFoundError, ConnectionRefusedError) as exc:
                sock.close()
                if time.monotonic() >= deadline:
                    raise can.CanInitializationError(
                        f"{self.channel_info}: no bus listens there ({exc.strerror}; the simulator's bus "
                        "listens: listen=true)") from None
                time.sleep(_CONNECT_RETRY_S)
            except OSError as exc:
                sock.close()
                raise can.CanInitializationError(f"{self.channel_info}: {exc.strerror or exc}") from None

    # -- receiving ------------------------------------------------------------------------------
    def _receive(self) -> None:
        """A connecting bus's receive thread: every message of the listener, in order; when
        the listener goes away, connects again until it is back (or the bus shuts down)."""
        sock = self._peers[0]
        while True:
            try:
                payload = sock.recv(MAX_MESSAGE)
            except OSError as exc:
                payload, reason = b"", exc.strerror or str(exc)
            else:
                reason = "it closed the connection"
            if payload:
                self._delivered(payload)
                continue
            if self._closed:
                return
            self._gone = f"the listening bus went away ({reason})"
            _log.warning("%s: %s; connecting again", self.channel_info, self._gone)
            sock = self._reconnect()
            if sock is None:
                return

    def _reconnect(self) -> socket.socket | None:
        """The connection to a listener on the path again (``None``: shut down meanwhile)."""
        while not self._closed:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            try:
                sock.connect(self.path)
            except OSError:
                sock.close()
                time.sleep(_RECONNECT_S)
                continue
            with self._send_lock:
                if self._closed:
                    break
                old, self._peers = self._peers, [sock]
                self._gone = None
            for dead in old:
                dead.close()
            _log.warning("%s: connected again", self.channel_info)
            return sock
        return None

    def _relay(self) -> None:
        """The listening bus's receive thread: accepts buses, and relays each message of one to
        the others before taking it itself."""
        selector = selectors.DefaultSelector()
        assert self._server is not None and self._wake is not None
        selector.register(self._server, selectors.EVENT_READ)
        selector.register(self._wake[1], selectors.EVENT_READ)
        try:
            while not self._closed:
                for key, _ in selector.select():
                    sock = key.fileobj
                    if sock is self._wake[1]:
                        return
                    if sock is self._server:
                        self._accept(selector)
                        continue
                    try:
                        payload = sock.recv(MAX_MESSAGE)  # type: ignore[union-attr]
                    except OSError:
                        payload = b""
                    if not payload:
                        selector.unregister(sock)
                        self._drop(sock)  # type: ignore[arg-type]
                        continue
                    self._send_to(payload, but=sock)  # type: ignore[arg-type]
                    self._delivered(payload)
        finally:
            selector.close()

    def _accept(self, selector: selectors.BaseSelector) -> None:
        try:
            sock, _ = self._server.accept()  # type: ignore[union-attr]
        except OSError:
            return
        with self._send_lock:
            if self._closed:
                sock.close()
                return
            self._peers.append(sock)
        selector.register(sock, selectors.EVENT_READ)

    def _delivered(self, payload: bytes) -> None:
        try:
            self._deliver(payload)
        except Exception:  # noqa: BLE001 - as a receive thread does: log, go on
            _log.exception("%s: receiving a message failed", self.channel_info)

    _gone: str | None = None
    """Why sends fail while a connecting bus has lost its listener (``None``: connected)."""

    # -- sending --------------------------------------------------------------------------------
    def _put(self, payload: bytes) -> None:
        if len(payload) > MAX_MESSAGE:
            raise can.CanOperationError(f"{self.channel_info}: a burst of {len(payload)} bytes, more than "
                                        f"{MAX_MESSAGE}")
        if self._closed:
            raise can.CanOperationError(f"{self.channel_info}: bus is shut down")
        if self._gone is not None:
            raise can.CanOperationError(f"{self.channel_info}: {self._gone}")
        self._send_to(payload)
        if self._own:
            self._deliver(payload)

    def _send_to(self, payload: bytes, but: socket.socket | None = None) -> None:
        """``payload`` to every peer but ``but``; a listening bus drops a peer that is gone, a
        connecting bus fails."""
        with self._send_lock:
            for sock in tuple(self._peers):
                if sock is but:
                    continue
                try:
                    sock.send(payload)
                except OSError as exc:
                    if not self.listening:
                        raise can.CanOperationError(f"{self.channel_info}: {exc.strerror or exc}") from exc
                    self._peers.remove(sock)  # its receive side unregisters and closes it

    def _drop(self, sock: socket.socket) -> None:
        with self._send_lock:
            if sock in self._peers:
                self._peers.remove(sock)
        sock.close()

    # -- closing --------------------------------------------------------------------------------
    def shutdown(self) -> None:
        with self._send_lock:
            if self._closed:
                return
            self._closed = True
            peers, self._peers = self._peers, []
        super().shutdown()
        if self._wake is not None:
            self._wake[0].send(b"x")  # the relay thread returns
        for sock in peers:
            try:
                sock.shutdown(socket.SHUT_RDWR)  # a connecting bus's receive returns
            except OSError:
                pass
        if self._receiver is not threading.current_thread():
            self._receiver.join(5.0)
        for sock in peers:
            sock.close()
        if self._server is not None:
            self._server.close()
            self._unlink_own()
        if self._wake is not None:
            for sock in self._wake:
                sock.close()

    def _unlink_own(self) -> None:
        """Remove the socket file if it is still this bus's (not a later listener's)."""
        try:
            info = os.stat(self.path)
            if (info.st_dev, info.st_ino) == self._inode:
                os.unlink(self.path)
        except OSError as exc:
            if exc.errno != errno.ENOENT:
                _log.debug("%s: %s", self.channel_info, exc)
