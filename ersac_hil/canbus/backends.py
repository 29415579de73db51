"""Which CAN backends this machine offers, and why not when one is missing."""
from __future__ import annotations

from dataclasses import dataclass

import can


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
    try:
        bus = can.Bus(interface="socketcan", channel=channel)
    except OSError as exc:
        if exc.errno == 97:
            why = "the kernel has no SocketCAN (CONFIG_CAN unset: address family not supported)"
        elif exc.errno == 19:
            why = f"no {channel} interface (create it: ip link add {channel} type vcan && ip link set {channel} up)"
        else:
            why = f"socketcan {channel}: {exc}"
        return BackendStatus("socketcan", False, why)
    except (ImportError, can.CanError) as exc:
        return BackendStatus("socketcan", False, f"socketcan {channel}: {exc}")
    bus.shutdown()
    return BackendStatus("socketcan", True, f"socketcan on {channel}")


def available_backends() -> list[BackendStatus]:
    """``virtual`` and the loopback hub always work; socketcan where the kernel has it."""
    return [BackendStatus("virtual", True, "in-process python-can virtual bus"),
            BackendStatus("remote", True, "loopback hub (python-can-remote on 127.0.0.1)"),
            vcan_status()]
