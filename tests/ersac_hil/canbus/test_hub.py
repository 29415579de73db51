"""The loopback CAN hub (python-can-remote in a thread): a client that goes away abruptly is no
traceback on stderr (socketserver prints one for every handler error, into whatever runs then:
another test's captured output), and ``close()`` leaves none of its threads behind."""
from __future__ import annotations

import socket
import struct
import threading

import pytest

from ersac_hil.canbus import LoopbackHub
from helpers.waiting import wait_until

pytestmark = pytest.mark.timeout(60)
UPGRADE = (b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
           b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Protocol: can.json.v1\r\n\r\n")


def _client(port: int) -> socket.socket:
    """A client through the hub's websocket handshake (the hub then waits for its bus request)."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.sendall(UPGRADE)
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += sock.recv(4096)
    assert answer.startswith(b"HTTP/1.1 101")
    return sock


def _hub_threads(before: set[threading.Thread]) -> list[threading.Thread]:
    return [t for t in set(threading.enumerate()) - before
            if t.is_alive() and any(part in t.name for part in ("process_request", "_send_to_client", "can-hub"))]


def test_a_vanished_client_prints_nothing_and_close_leaves_no_thread(capfd):
    """One client gone with a TCP reset (as a killed process whose unread frames were still
    queued: socketserver printed its 40-dash tail for it), one still connected when the hub
    closes."""
    before = set(threading.enumerate())
    hub = LoopbackHub()
    staying = None
    try:
        gone = _client(hub.port)
        gone.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        gone.close()
        staying = _client(hub.port)
        wait_until(lambda: len(_hub_threads(before)) >= 2, 20, what="the hub's thread and the staying client's")
    finally:
        hub.close()
        left = _hub_threads(before)
        if staying is not None:
            staying.close()
    err = capfd.readouterr().err
    assert "Exception occurred during processing of request" not in err and "Traceback" not in err, err
    assert not left, left
