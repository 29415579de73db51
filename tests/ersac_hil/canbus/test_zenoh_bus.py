"""The CAN-over-Zenoh python-can plugin: real buses through the session's embedded router.

The CiA 301 conformance suite and the agent tests also run on it (``can_backend`` "zenoh",
and "zenoh-tls" through a router with TLS and access control);
here: the wire format, what python-can users rely on (entry point, order, own frames, filters,
periodic tasks with modify_data), refusals, a bus spanning two processes, and a bus through
a secured router (TLS, the roles' certificates and access control).
"""
from __future__ import annotations

import contextlib
import inspect
import json
import subprocess
import sys
import time
import uuid

import can
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.canbus.zenoh_bus import (NOT_DATA, ZenohBus, decode_frame, decode_frames, encode_data_frames,
                                       encode_frame)

TIMEOUT = 10.0


def _channel(router) -> str:  # noqa: ANN001
    return f"t-{uuid.uuid4().hex[:8]}@{router.endpoint}"


@pytest.fixture
def pair(can_router):
    channel = _channel(can_router)
    a = can.Bus(interface="zenoh", channel=channel)
    b = can.Bus(interface="zenoh", channel=channel)
    _wait_linked(a, b)
    yield a, b
    a.shutdown()
    b.shutdown()


def _wait_linked(a: can.BusABC, b: can.BusABC) -> None:
    """Until a frame from ``a`` reaches ``b`` (subscriptions propagate asynchronously)."""
    deadline = time.monotonic() + TIMEOUT
    probe = can.Message(arbitration_id=0x7FF, data=b"probe")
    while time.monotonic() < deadline:
        a.send(probe)
        if b.recv(0.05) is not None:
            while b.recv(0.05) is not None:
                pass
            return
    pytest.fail("the two buses never linked")


frames = st.builds(
    lambda ext, ident, data, fd, brs, esi: can.Message(
        arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF), is_extended_id=ext, data=data,
        is_fd=fd, bitrate_switch=brs and fd, error_state_indicator=esi and fd),
    st.booleans(), st.integers(0, 0x1FFFFFFF), st.binary(max_size=8), st.booleans(), st.booleans(),
    st.booleans())


@given(frames)
def test_the_wire_format_round_trips_every_field(msg):
    back = decode_frame(encode_frame(msg), "c")
    assert back.equals(msg, timestamp_delta=None, check_channel=False, check_direction=False)
    assert back.is_rx and back.channel == "c"


@given(st.lists(frames, min_size=1, max_size=20))
def test_a_burst_splits_back_into_its_frames(msgs):
    back = decode_frames(b"".join(encode_frame(m) for m in msgs))
    assert len(back) == len(msgs)
    assert all(b.equals(m, timestamp_delta=None, check_channel=False, check_direction=False)
               for b, m in zip(back, msgs))


@given(st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), min_size=1, max_size=20))
def test_data_frames_have_the_wire_bytes_of_the_equivalent_messages(frames_):
    msgs = [can.Message(arbitration_id=i, data=d, is_extended_id=False) for i, d in frames_]
    assert encode_data_frames(frames_) == b"".join(encode_frame(m) for m in msgs)


def test_remote_frames_keep_their_dlc_without_data():
    msg = can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1)
    back = decode_frame(encode_frame(msg))
    assert back.is_remote_frame and back.dlc == 1 and len(back.data) == 0


@pytest.mark.parametrize("payload, match", [
    (b"", "without a frame"), (b"\x01\x02", "shorter than a frame header"),
    (encode_frame(can.Message(arbitration_id=1, data=b"abcd")) [:-1], "needs 4 data bytes")])
def test_payloads_that_are_not_whole_frames_are_refused(payload, match):
    with pytest.raises(ValueError, match=match):
        decode_frames(payload)


def test_the_entry_point_opens_it_and_frames_arrive_in_order(pair):
    a, b = pair
    assert isinstance(a, ZenohBus)
    sent = [can.Message(arbitration_id=0x180 + i % 7, data=bytes([i % 256, i // 256])) for i in range(300)]
    for msg in sent:
        a.send(msg)
    got = [b.recv(TIMEOUT) for _ in sent]
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(m.arbitration_id, bytes(m.data)) for m in sent]
    assert a.recv(0.1) is None  # a bus does not hear itself by default


def test_a_burst_arrives_as_single_frames_in_order(pair):
    a, b = pair
    sent = [can.Message(arbitration_id=0x190 + i, data=bytes([i] * (i % 9))) for i in range(13)]
    a.send_many(sent)
    a.send(can.Message(arbitration_id=0x80, data=b""))
    got = [b.recv(TIMEOUT) for _ in range(14)]
    assert [(m.arbitration_id, bytes(m.data)) for m in got[:13]] == [(m.arbitration_id, bytes(m.data)) for m in sent]
    assert got[13].arbitration_id == 0x80


def test_own_frames_on_request_and_other_channels_stay_apart(can_router):
    channel = _channel(can_router)
    own = can.Bus(interface="zenoh", channel=channel, receive_own_messages=True)
    other = can.Bus(interface="zenoh", channel=_channel(can_router))
    try:
        own.send(can.Message(arbitration_id=0x123, data=b"x"))
        echo = own.recv(TIMEOUT)
        assert echo is not None and echo.arbitration_id == 0x123
        assert other.recv(0.2) is None
    finally:
        own.shutdown()
        other.shutdown()


def test_filters_apply(can_router):
    channel = _channel(can_router)
    a = can.Bus(interface="zenoh", channel=channel)
    b = can.Bus(interface="zenoh", channel=channel, can_filters=[{"can_id": 0x181, "can_mask": 0x7FF}])
    try:
        deadline = time.monotonic() + TIMEOUT
        got = None
        while got is None and time.monotonic() < deadline:
            a.send(can.Message(arbitration_id=0x182, data=b"no"))
            a.send(can.Message(arbitration_id=0x181, data=b"yes"))
            got = b.recv(0.1)
        assert got is not None and got.arbitration_id == 0x181
    finally:
        a.shutdown()
        b.shutdown()


def test_periodic_tasks_change_their_data(pair):
    """python-can-remote 0.3 cannot (its ``CyclicSendTask.modify_data`` raises TypeError, see
    ersac_hil/canbus/heartbeat.py); heartbeats depend on it."""
    a, b = pair
    task = a.send_periodic(can.Message(arbitration_id=0x701, data=[0x7F]), period=0.01)
    try:
        task.modify_data(can.Message(arbitration_id=0x701, data=[0x05]))
        deadline = time.monotonic() + TIMEOUT
        seen = None
        while time.monotonic() < deadline and seen != b"\x05":
            msg = b.recv(TIMEOUT)
            seen = bytes(msg.data) if msg is not None else None
        assert seen == b"\x05"
    finally:
        task.stop()


@pytest.mark.parametrize("channel, match", [
    ("can0", "no Zenoh endpoint"),
    ("can0@", "no Zenoh endpoint"),
    ("bad/name@tcp/127.0.0.1:7447", "not a valid key chunk"),
    ("can0@tcp/10.1.2.3:7447", "loopback"),
])
def test_bad_channels_are_refused(channel, match):
    with pytest.raises(can.CanInitializationError, match=match):
        can.Bus(interface="zenoh", channel=channel)


def test_no_router_is_an_initialisation_error():
    from ersac_hil.zenoh_session import free_tcp_port
    with pytest.raises(can.CanInitializationError):
        can.Bus(interface="zenoh", channel=f"c@tcp/127.0.0.1:{free_tcp_port()}", connect_timeout=0.3)


def test_the_bus_spans_processes(can_router):
    channel = _channel(can_router)
    bus = can.Bus(interface="zenoh", channel=channel)
    code = (
        "import can, sys\n"
        f"bus = can.Bus(interface='zenoh', channel={channel!r})\n"
        "msg = bus.recv(20.0)\n"
        "bus.send(can.Message(arbitration_id=msg.arbitration_id + 1, data=bytes(msg.data)[::-1]))\n"
        "bus.shutdown()\n")
    child = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 30
        reply = None
        while reply is None and time.monotonic() < deadline and child.poll() is None:
            bus.send(can.Message(arbitration_id=0x200, data=b"\x01\x02\x03"))
            reply = bus.recv(0.2)
        assert reply is not None and reply.arbitration_id == 0x201 and bytes(reply.data) == b"\x03\x02\x01"
        assert child.wait(30) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        bus.shutdown()


def test_pushed_frames_reach_listeners_in_order_until_stopped(pair):
    """open_network's path: listeners on Zenoh's receive thread, no Notifier polling recv()."""
    import threading
    a, b = pair
    got: list[int] = []
    done = threading.Event()

    def listener(msg: can.Message) -> None:
        got.append(msg.arbitration_id)
        if len(got) == 200:
            done.set()

    notifier = b.push_notifier([listener])
    with pytest.raises(can.CanOperationError, match="already attached"):
        b.push_notifier([listener])
    for i in range(200):
        a.send(can.Message(arbitration_id=i, data=b""))
    assert done.wait(TIMEOUT) and got == list(range(200))
    notifier.stop()
    a.send(can.Message(arbitration_id=0x300, data=b""))
    assert b.recv(TIMEOUT).arbitration_id == 0x300 and len(got) == 200  # queued for recv() again


def test_frame_listeners_get_data_frames_without_messages_others_get_messages(pair):
    """canopen's path (protocol.can.busconfig.FrameListener): on_frame(can_id, data, ts)."""
    import threading
    a, b = pair
    raw: list[tuple[int, bytes]] = []
    msgs: list[can.Message] = []
    done = threading.Event()

    class Raw:
        def on_frame(self, can_id, data, timestamp):
            assert isinstance(data, bytearray) and timestamp > 0
            raw.append((can_id, bytes(data)))

    def listener(msg: can.Message) -> None:
        msgs.append(msg)
        if len(msgs) == 15:
            done.set()

    b.push_notifier([Raw(), listener])
    sent = [(0x180 + i, bytes([i] * (i % 9))) for i in range(13)]
    a.send_data_frames(sent)
    a.send_many([can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False),
                 can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)])
    assert done.wait(TIMEOUT)
    assert raw == sent + [(0x80, b"")]  # no remote frame for a canopen network
    assert [(m.arbitration_id, bytes(m.data)) for m in msgs] == sent + [(0x701, b""), (0x80, b"")]
    assert msgs[13].is_remote_frame and all(m.is_rx and not m.is_extended_id for m in msgs)


def test_an_interceptor_takes_a_sample_at_once_and_listeners_get_what_it_leaves(pair):
    """The agent's TPDO path: one call per sample before the listeners (and their filters)."""
    import threading
    from helpers.waiting import wait_until
    REMOTE = 2  # the wire format's flag bit 1, one of NOT_DATA
    assert NOT_DATA & REMOTE
    a, b = pair
    samples: list[list[tuple[int, int, bytes]]] = []
    msgs: list[can.Message] = []
    done = threading.Event()

    def take(frames, timestamp):  # noqa: ANN001
        assert timestamp > 0 and all(isinstance(f[3], bytearray) for f in frames)
        samples.append([(f[0], f[1], bytes(f[3])) for f in frames])
        return [f for f in frames if f[0] >= 0x200]  # keeps the 0x1xx frames

    def listener(msg: can.Message) -> None:
        msgs.append(msg)
        if msg.arbitration_id == 0x7FF:
            done.set()

    notifier = b.push_notifier([listener])
    notifier.intercept(take)
    sent = [(0x180 + i, bytes([i] * (i % 9))) for i in range(4)] + [(0x200 + i, bytes([i])) for i in range(3)]
    a.send_data_frames(sent)
    a.send_many([can.Message(arbitration_id=0x181, is_remote_frame=True, dlc=1, is_extended_id=False),
                 can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False)])
    assert done.wait(TIMEOUT)
    assert samples == [[(i, 0, d) for i, d in sent], [(0x181, REMOTE, b""), (0x7FF, 0, b"")]]
    assert [(m.arbitration_id, bytes(m.data)) for m in msgs] == sent[4:] + [(0x7FF, b"")]
    b.set_filters([{"can_id": 0x201, "can_mask": 0x7FF}])  # filters: the interceptor still sees all
    done.clear()
    notifier.intercept(lambda frames, ts: (done.set(), frames)[1])
    a.send_data_frames(sent)
    assert done.wait(TIMEOUT)
    notifier.intercept(lambda frames, ts: 1 / 0)  # its error is kept; nothing more delivered
    a.send_data_frames(sent)
    wait_until(lambda: notifier.exception is not None, what="the interceptor's error kept")
    assert isinstance(notifier.exception, ZeroDivisionError)
    assert [m.arbitration_id for m in msgs] == [i for i, _ in sent[4:]] + [0x7FF, 0x201]


def _link(sender: can.BusABC, receiver: can.BusABC, arbitration_id: int) -> can.Message | None:
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        sender.send(can.Message(arbitration_id=arbitration_id, data=b"\x01"))
        got = receiver.recv(0.05)
        if got is not None:
            return got
    return None


def test_agent_and_simulator_share_a_bus_over_tls_and_other_roles_are_kept_off(secure_can_router):
    """The demo's --secure CAN bus: endpoints and identities from the roles' config files."""
    channel = f"s-{uuid.uuid4().hex[:8]}"
    buses = {role: can.Bus(interface="zenoh", channel=channel, zenoh_config=str(secure_can_router.configs[role]))
             for role in ("agent", "simulator", "observer")}
    try:
        agent, simulator, observer = buses["agent"], buses["simulator"], buses["observer"]
        assert "tls/127.0.0.7:" in agent.channel_info  # endpoints from the file
        assert _link(simulator, agent, 0x181) is not None and _link(agent, simulator, 0x201) is not None
        for _ in range(20):
            observer.send(can.Message(arbitration_id=0x7, data=b"\x00"))  # dropped by the router
        simulator.send(can.Message(arbitration_id=0x182, data=b"\x02"))
        heard = [m.arbitration_id for m in iter(lambda: agent.recv(1.0), None)]
        assert 0x182 in heard and 0x7 not in heard
        assert observer.recv(0.2) is None  # nor does it hear the bus
    finally:
        for bus in buses.values():
            bus.shutdown()


def test_a_plain_channel_cannot_reach_the_secured_router(secure_can_router):
    endpoint = json.loads(zenoh.Config.from_file(str(secure_can_router.configs["agent"])).get_json("connect/endpoints"))[0]
    with pytest.raises(can.CanInitializationError):
        can.Bus(interface="zenoh", channel=f"c@tcp/{endpoint.split('/', 1)[1]}", connect_timeout=0.5)


@pytest.mark.parametrize("kwargs, match", [
    ({"zenoh_config": "/nonexistent/agent.json5"}, "no such file"),
    ({"insecure": "maybe"}, "insecure must be true or false"),
    ({"mode": "router"}, "client or peer"),
    ({"lowlatency": "maybe"}, "lowlatency must be true or false"),
    ({"busy_poll": "soon"}, "busy_poll must be a number of seconds"),
    ({"busy_poll": -0.001}, "busy_poll must be finite and >= 0"),
    ({"busy_poll": "nan"}, "busy_poll must be finite and >= 0"),
    ({"busy_poll": "inf"}, "busy_poll must be finite and >= 0"),
])
def test_bad_session_arguments_are_refused(kwargs, match):
    with pytest.raises(can.CanInitializationError, match=match):
        can.Bus(interface="zenoh", channel="c@tcp/127.0.0.1:7447", **kwargs)


def test_shutdown_while_another_thread_sends_is_clean(can_router):
    """A bus shut down while another thread is sending (a simulator's SYNC thread at the end of a
    run): the shutdown completes without error and the sender gets CanOperationError."""
    import threading
    for _ in range(30):
        bus = can.Bus(interface="zenoh", channel=f"race-{uuid.uuid4().hex[:8]}@{can_router.endpoint}")
        errors: list[BaseException] = []
        started = threading.Event()

        def send() -> None:
            msg = can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False)
            started.set()
            try:
                while True:
                    bus.send(msg)
            except can.CanOperationError:
                return
            except BaseException as exc:  # noqa: BLE001 - anything else is the failure
                errors.append(exc)
        sender = threading.Thread(target=send)
        sender.start()
        started.wait(5)
        bus.shutdown()
        sender.join(5)
        assert not sender.is_alive() and errors == []


# -- busy polling ---------------------------------------------------------------------------

@contextlib.contextmanager
def _polling_link(router, busy_poll):  # noqa: ANN001, ANN202
    """A plain bus and a busy-polling bus on a new channel, linked; both shut down after."""
    channel = _channel(router)
    a = can.Bus(interface="zenoh", channel=channel)
    b = can.Bus(interface="zenoh", channel=channel, busy_poll=busy_poll)
    try:
        _wait_linked(a, b)
        yield a, b
    finally:
        a.shutdown()
        b.shutdown()


@pytest.fixture(scope="module")
def polling_pair(can_router):
    """A plain bus and a busy-polling bus (1 ms, given as python-can configuration's string)."""
    with _polling_link(can_router, "0.001") as pair:
        yield pair


def _wire(msgs: list[can.Message]) -> list[bytes]:
    return [encode_frame(m) for m in msgs]


@given(bursts=st.lists(st.lists(frames, min_size=1, max_size=13), min_size=1, max_size=6),
       pauses=st.lists(st.sampled_from([0.0, 0.0, 0.003]), min_size=6, max_size=6))
def test_a_busy_polling_bus_gets_every_frame_in_order(polling_pair, bursts, pauses):
    """Bursts and single frames, some after the polling window has run out (the thread then
    blocks in Zenoh's channel): every frame arrives once, in order, as sent."""
    a, b = polling_pair
    sent: list[can.Message] = []
    for burst, pause in zip(bursts, pauses):
        if pause:
            time.sleep(pause)  # not a synchronisation: lets the receive thread go back to blocking
        if len(burst) == 1:
            a.send(burst[0])
        else:
            a.send_many(burst)
        sent += burst
    got = [b.recv(TIMEOUT) for _ in sent]
    assert None not in got
    assert _wire(got) == _wire(sent)
    assert b.recv(0.02) is None


def _rx_threads() -> list:
    import threading
    return [t for t in threading.enumerate() if t.name.startswith("zenoh-can-rx")]


def test_a_busy_polling_bus_pushes_on_its_receive_thread_which_ends_at_shutdown(can_router):
    import threading
    with _polling_link(can_router, 0.002) as (a, b):
        got: list[tuple[int, str]] = []
        done = threading.Event()

        def listener(msg: can.Message) -> None:
            got.append((msg.arbitration_id, threading.current_thread().name))
            if len(got) == 20:
                done.set()
        b.push_notifier([listener])
        for k in range(10):
            a.send_many([can.Message(arbitration_id=0x180 + k, data=b"x"),
                         can.Message(arbitration_id=0x280 + k, data=b"y")])
        assert done.wait(TIMEOUT)
        assert [i for i, _ in got] == [i for k in range(10) for i in (0x180 + k, 0x280 + k)]
        assert {name for _, name in got} == {f"zenoh-can-rx {b.key}"}
    assert not any(t.name == f"zenoh-can-rx {b.key}" for t in _rx_threads())


def _blocked_in_recv(thread) -> bool:  # noqa: ANN001
    """``thread`` (a busy-polling bus's receive thread) is in the blocking ``recv`` of Zenoh's
    channel, not in its polling loop: its Python frame is at that call (the polling loop
    never reaches it while its window is open)."""
    lines, first = inspect.getsourcelines(ZenohBus._receive)
    at = first + next(i for i, line in enumerate(lines) if "sample = recv()" in line)
    frame = sys._current_frames().get(thread.ident)
    return frame is not None and frame.f_code is ZenohBus._receive.__code__ and frame.f_lineno == at


def test_a_busy_polling_bus_blocks_once_frames_stop(can_router):
    """It polls only within ``busy_poll`` of the last frame, then blocks in Zenoh's channel
    (idle, its thread uses no processor), and the next frame wakes it."""
    with _polling_link(can_router, 0.05) as (a, b):
        thread = next(t for t in _rx_threads() if t.name.endswith(b.key))
        for k in range(3):
            a.send(can.Message(arbitration_id=0x120 + k, data=b"go"))  # opens the polling window
            assert b.recv(TIMEOUT) is not None
            from helpers.waiting import wait_until
            wait_until(lambda: _blocked_in_recv(thread), what="the receive thread blocked after its window")
