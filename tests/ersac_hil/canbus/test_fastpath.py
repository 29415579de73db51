"""The declared fast paths (``protocol.can.fastpath``): CAN over Zenoh declares them and gets
them from ``open_network``, a plain python-can bus does not and gets the ordinary paths; both
deliver the same frames."""
from __future__ import annotations

import threading
import uuid

import can
from can.interfaces.virtual import VirtualBus

from ersac_hil.canbus.zenoh_bus import PushNotifier, ZenohBus
from protocol.can.busconfig import BusConfig, open_network, send_frames
from protocol.can.fastpath import BurstNotifier, BurstSender, FramePusher

FRAMES = [(0x201, b"\x01\x02"), (0x202, b""), (0x080, b"")]


def test_can_over_zenoh_declares_every_fast_path():
    assert issubclass(ZenohBus, BurstSender) and issubclass(ZenohBus, FramePusher)
    assert issubclass(PushNotifier, BurstNotifier)
    assert not issubclass(VirtualBus, (BurstSender, FramePusher))


def _received(config: BusConfig) -> list[tuple[int, bytes]]:
    """Frames sent with ``send_frames`` on one network of ``config`` as a second one gets them."""
    sender, receiver = open_network(config), open_network(config)
    got: list[tuple[int, bytes]] = []
    done = threading.Event()

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        got.append((can_id, bytes(data)))
        if len(got) == len(FRAMES):
            done.set()

    try:
        for cob_id, _ in FRAMES:
            receiver.subscribe(cob_id, on_frame)
        for _ in range(200):  # until the link carries frames (subscriptions propagate asynchronously)
            send_frames(sender, FRAMES)
            if done.wait(0.05):
                break
        assert done.is_set()
        return got[:len(FRAMES)]
    finally:
        sender.disconnect()
        receiver.disconnect()


def test_open_network_takes_the_fast_paths_of_a_bus_that_declares_them(can_router):
    config = BusConfig("zenoh", f"t-{uuid.uuid4().hex[:8]}@{can_router.endpoint}")
    network = open_network(config)
    try:
        assert network.burst is network.bus and isinstance(network.notifier, BurstNotifier)
    finally:
        network.disconnect()
    assert _received(config) == FRAMES


def test_a_plain_bus_gets_the_ordinary_paths_and_the_same_frames():
    config = BusConfig("virtual", f"t-{uuid.uuid4().hex[:8]}")
    network = open_network(config)
    try:
        assert network.burst is None and isinstance(network.notifier, can.Notifier)
    finally:
        network.disconnect()
    assert _received(config) == FRAMES
