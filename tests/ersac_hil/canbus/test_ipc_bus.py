"""CAN over a Unix socket (``interface="ipc"``): real sockets, real processes.

The CiA 301 / CiA 402 conformance suites and the agent tests also run on it (``can_backend``
"ipc"); here: what python-can users rely on (entry point, order, own frames, filters, bursts,
push delivery), the listener's relay, who may connect, refusals, the listener going away, and
clean shutdown."""
from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import threading
import time

import can
import pytest

from ersac_hil.canbus.frames import PushNotifier
from ersac_hil.canbus.ipc import MAX_MESSAGE, IpcBus
from protocol.can.busconfig import BusConfig, open_network, send_frames
from protocol.can.fastpath import BurstNotifier, BurstSender, FramePusher

TIMEOUT = 10.0


@pytest.fixture
def path(tmp_path):
    return str(tmp_path / "can.sock")


@pytest.fixture
def trio(path):
    """A listening bus and two connected to it."""
    buses = [can.Bus(interface="ipc", channel=path, listen=True)]
    try:
        buses += [can.Bus(interface="ipc", channel=path), can.Bus(interface="ipc", channel=path)]
        _wait_accepted(*buses)
        yield buses
    finally:
        for bus in buses:
            bus.shutdown()


def _wait_accepted(listener: IpcBus, *connected: IpcBus) -> None:
    """Until the listener took every connection (its receive thread accepts them)."""
    deadline = time.monotonic() + TIMEOUT
    while len(listener._peers) < len(connected):
        assert time.monotonic() < deadline, "the listener never accepted its buses"
        time.sleep(0.01)


def _ids(msgs) -> list[tuple[int, bytes]]:  # noqa: ANN001
    return [(m.arbitration_id, bytes(m.data)) for m in msgs]


def test_it_declares_every_fast_path():
    assert issubclass(IpcBus, BurstSender) and issubclass(IpcBus, FramePusher)
    assert issubclass(PushNotifier, BurstNotifier)


def test_every_frame_reaches_every_other_bus_in_order(trio):
    listener, a, b = trio
    assert isinstance(a, IpcBus) and listener.listening and not a.listening
    sent = [can.Message(arbitration_id=0x180 + i % 7, data=bytes([i % 256, i // 256])) for i in range(300)]
    for msg in sent:
        a.send(msg)  # relayed by the listener to b
    assert _ids(listener.recv(TIMEOUT) for _ in sent) == _ids(sent)
    assert _ids(b.recv(TIMEOUT) for _ in sent) == _ids(sent)
    listener.send(can.Message(arbitration_id=0x80, data=b""))
    assert a.recv(TIMEOUT).arbitration_id == 0x80 and b.recv(TIMEOUT).arbitration_id == 0x80
    assert a.recv(0.1) is None and listener.recv(0.1) is None  # nobody hears itself by default


def test_a_burst_arrives_as_single_frames_in_order_with_every_field(trio):
    listener, a, _ = trio
    sent = [can.Message(arbitration_id=0x190 + i, data=bytes([i] * (i % 9))) for i in range(13)]
    sent += [can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, data=b"x"),
             can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1),
             can.Message(arbitration_id=0x123, is_fd=True, bitrate_switch=True, data=bytes(range(64)))]
    a.send_many(sent)
    got = [listener.recv(TIMEOUT) for _ in sent]
    assert all(g.equals(m, timestamp_delta=None, check_channel=False, check_direction=False)
               for g, m in zip(got, sent))
    assert all(g.is_rx and g.channel == listener.path for g in got)


def test_own_frames_on_request_and_filters_apply(path):
    listener = can.Bus(interface="ipc", channel=path, listen=True, receive_own_messages="true")
    other = can.Bus(interface="ipc", channel=path, can_filters=[{"can_id": 0x200, "can_mask": 0x7F0}])
    try:
        _wait_accepted(listener, other)
        listener.send_data_frames([(0x123, b"x"), (0x201, b"y")])
        assert _ids([listener.recv(TIMEOUT), listener.recv(TIMEOUT)]) == [(0x123, b"x"), (0x201, b"y")]
        assert _ids([other.recv(TIMEOUT)]) == [(0x201, b"y")] and other.recv(0.1) is None
    finally:
        other.shutdown()
        listener.shutdown()


def test_pushed_frames_reach_frame_listeners_without_messages_and_stop(trio):
    listener, a, _ = trio
    raw: list[tuple[int, bytes]] = []
    done = threading.Event()

    class Raw:
        def on_frame(self, can_id, data, timestamp):  # noqa: ANN001
            assert isinstance(data, bytearray) and timestamp > 0
            raw.append((can_id, bytes(data)))
            if len(raw) == 200:
                done.set()

    notifier = a.push_notifier([Raw()])
    with pytest.raises(can.CanOperationError, match="already attached"):
        a.push_notifier([Raw()])
    sent = [(i, bytes([i % 256])) for i in range(200)]
    for i in range(0, 200, 20):
        listener.send_data_frames(sent[i:i + 20])
    assert done.wait(TIMEOUT) and raw == sent
    notifier.stop()
    listener.send(can.Message(arbitration_id=0x300, data=b""))
    assert a.recv(TIMEOUT).arbitration_id == 0x300 and len(raw) == 200  # queued for recv() again


def test_canopen_networks_take_its_fast_paths(path):
    listener = open_network(BusConfig("ipc", path, options=(("listen", "true"),)))
    other = open_network(BusConfig("ipc", path))
    got: list[tuple[int, bytes]] = []
    done = threading.Event()
    frames = [(0x201, b"\x01\x02"), (0x202, b""), (0x080, b"")]

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        got.append((can_id, bytes(data)))
        if len(got) == len(frames):
            done.set()

    try:
        assert other.burst is other.bus and isinstance(other.notifier, BurstNotifier)
        for cob_id, _ in frames:
            listener.subscribe(cob_id, on_frame)
        send_frames(other, frames)
        assert done.wait(TIMEOUT) and got == frames
    finally:
        other.disconnect()
        listener.disconnect()


def test_only_its_user_may_connect_and_shutdown_removes_the_socket(path):
    listener = can.Bus(interface="ipc", channel=path, listen=True)
    try:
        assert stat.S_ISSOCK(os.stat(path).st_mode) and stat.S_IMODE(os.stat(path).st_mode) == 0o600
    finally:
        listener.shutdown()
    assert not os.path.exists(path)
    assert not [t for t in threading.enumerate() if t.name.startswith("ipc-can-rx")]


@pytest.mark.parametrize("channel, kwargs, match", [
    ("", {}, "must be a socket path"),
    (None, {}, "must be a socket path"),
    ("a\0b", {}, "no NUL byte"),
    ("/tmp/" + "x" * 120, {}, "longer than a Unix socket path"),
    ("/tmp/x.sock", {"listen": "maybe"}, "listen must be true or false"),
    ("/tmp/x.sock", {"connect_timeout": "soon"}, "connect_timeout must be a number of seconds"),
])
def test_bad_arguments_are_refused(channel, kwargs, match):
    with pytest.raises(can.CanInitializationError, match=match):
        can.Bus(interface="ipc", channel=channel, **kwargs)


def test_nobody_listening_is_an_initialisation_error(path):
    with pytest.raises(can.CanInitializationError, match="no bus listens there"):
        can.Bus(interface="ipc", channel=path, connect_timeout=0.1)


def test_a_live_listener_is_kept_a_stale_socket_replaced_another_file_refused(path, tmp_path):
    first = can.Bus(interface="ipc", channel=path, listen=True)
    try:
        with pytest.raises(can.CanInitializationError, match="another bus already listens"):
            can.Bus(interface="ipc", channel=path, listen=True)
    finally:
        first.shutdown()
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    stale.bind(path)  # bound, never listening: what a killed listener leaves
    stale.close()
    second = can.Bus(interface="ipc", channel=path, listen=True)
    second.shutdown()
    plain = tmp_path / "plain"
    plain.write_text("not a socket")
    with pytest.raises(can.CanInitializationError, match="exists and is not a socket"):
        can.Bus(interface="ipc", channel=str(plain), listen=True)
    assert plain.read_text() == "not a socket"


def test_a_bus_leaving_does_not_disturb_the_others(trio):
    listener, a, b = trio
    a.shutdown()
    deadline = time.monotonic() + TIMEOUT
    while len(listener._peers) > 1:  # the listener noticed
        assert time.monotonic() < deadline
        time.sleep(0.01)
    b.send(can.Message(arbitration_id=0x111, data=b"z"))
    listener.send(can.Message(arbitration_id=0x112, data=b""))
    assert listener.recv(TIMEOUT).arbitration_id == 0x111 and b.recv(TIMEOUT).arbitration_id == 0x112


def test_sends_fail_while_the_listener_is_away_and_the_bus_connects_again(path):
    listener = can.Bus(interface="ipc", channel=path, listen=True)
    network = open_network(BusConfig("ipc", path))
    bus = network.bus
    try:
        _wait_accepted(listener, bus)
        listener.shutdown()
        deadline = time.monotonic() + TIMEOUT
        while bus._gone is None:
            assert time.monotonic() < deadline, "the loss was never noticed"
            time.sleep(0.01)
        with pytest.raises(can.CanOperationError, match="went away"):
            bus.send(can.Message(arbitration_id=0x1, data=b""))
        listener = can.Bus(interface="ipc", channel=path, listen=True)  # the simulator restarted
        _wait_accepted(listener, bus)
        got = threading.Event()
        network.subscribe(0x181, lambda *_: got.set())
        listener.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        assert got.wait(TIMEOUT)
        bus.send(can.Message(arbitration_id=0x201, data=b"\x02"))
        assert listener.recv(TIMEOUT).arbitration_id == 0x201
        network.check()  # nothing recorded: the network goes on
    finally:
        network.disconnect()
        listener.shutdown()
    assert not [t for t in threading.enumerate() if t.name.startswith("ipc-can-rx")]


def test_a_burst_larger_than_a_message_is_refused(trio):
    _, a, _ = trio
    frames = [(0x100, bytes(8))] * (MAX_MESSAGE // 15 + 1)
    with pytest.raises(can.CanOperationError, match="more than"):
        a.send_data_frames(frames)


def test_the_bus_spans_processes(path):
    bus = can.Bus(interface="ipc", channel=path, listen=True)
    code = (
        "import can\n"
        f"bus = can.Bus(interface='ipc', channel={path!r})\n"
        "msg = bus.recv(20.0)\n"
        "bus.send(can.Message(arbitration_id=msg.arbitration_id + 1, data=bytes(msg.data)[::-1]))\n"
        "bus.shutdown()\n")
    with subprocess.Popen([sys.executable, "-c", code]) as child:
        try:
            deadline = time.monotonic() + 30
            while not bus._peers:
                assert time.monotonic() < deadline and child.poll() is None, "the child never connected"
                time.sleep(0.01)
            bus.send(can.Message(arbitration_id=0x200, data=b"\x01\x02\x03"))
            reply = bus.recv(30)
            assert reply is not None and (reply.arbitration_id, bytes(reply.data)) == (0x201, b"\x03\x02\x01")
            assert child.wait(30) == 0
        finally:
            child.kill()  # no-op once it ended
            bus.shutdown()


def test_the_agent_heartbeat_goes_on_after_the_bus_was_down(path):
    from ersac_hil.canbus.heartbeat import HeartbeatProducer
    from protocol.can import cobid
    from protocol.can.devices import AGENT_NODE_ID

    listener = can.Bus(interface="ipc", channel=path, listen=True)
    network = open_network(BusConfig("ipc", path))
    beat = HeartbeatProducer(network, period_s=0.01)
    try:
        _wait_accepted(listener, network.bus)
        beat.start()
        assert listener.recv(TIMEOUT).arbitration_id == cobid.heartbeat(AGENT_NODE_ID)
        listener.shutdown()
        deadline = time.monotonic() + TIMEOUT
        while network.bus._gone is None:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        time.sleep(0.05)  # a few beats fail meanwhile
        listener = can.Bus(interface="ipc", channel=path, listen=True)
        assert listener.recv(TIMEOUT).arbitration_id == cobid.heartbeat(AGENT_NODE_ID)
        assert beat.running
    finally:
        beat.stop()
        network.disconnect()
        listener.shutdown()
