"""Which CAN backends this machine offers, and why not when one is missing."""
from __future__ import annotations

from dataclasses import dataclass

import can

from protocol.can.busconfig import BusConfig, open_bus, unavailable_reason


@dataclass(frozen=True)
class BackendStatus:
    name: str
    available: bool
    reason: str


def vcan_status(channel: str = "vcan0") -> BackendStatus:
    """Try to open ``socketcan`` on ``channel``; say why it failed when it does.

    Creating the interface (``ip link add vcan0 type vcan``) needs root and a kernel with
    CONFIG_CAN_VCAN; this only probes, it never changes the system.
    """
    config = BusConfig("socketcan", channel)
    try:
        bus = open_bus(config)
    except (OSError, ImportError, can.CanError) as exc:
        return BackendStatus("socketcan", False, unavailable_reason(config, exc))
    bus.shutdown()
    return BackendStatus("socketcan", True, f"socketcan on {channel}")


def available_backends() -> list[BackendStatus]:
    """``virtual`` and the loopback hub always work; socketcan where the kernel has it."""
    return [BackendStatus("virtual", True, "in-process python-can virtual bus"),
            BackendStatus("remote", True, "loopback hub (python-can-remote on 127.0.0.1)"),
            vcan_status()]
