"""Endpoint policy: the form of an endpoint, loopback or not, secured or not, free ports."""
from __future__ import annotations

import ipaddress
import re
import socket
from typing import Any

from .errors import EndpointError

__all__ = ["DEFAULT_ENDPOINT", "SECURE_PROTOCOLS", "loopback_endpoint", "split_endpoint", "is_loopback",
           "check_endpoint", "free_tcp_port"]

#: Where clients connect and the router listens unless told otherwise.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: Link protocols that are encrypted and authenticated (TLS); fine off loopback.
SECURE_PROTOCOLS: tuple[str, ...] = ("tls", "quic")
_ENDPOINT = re.compile(
    r"(?P<proto>[a-z][a-z0-9-]*)/(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[^/:?#\[\]\s]+)):(?P<port>[0-9]{1,5})"
    r"(?P<rest>[?#][^\s]*)?")


def loopback_endpoint(port: int, host: str = "127.0.0.1", protocol: str = "tcp") -> str:
    """``tcp/127.0.0.1:<port>`` (or another loopback host / protocol), checked."""
    endpoint = check_endpoint(f"{protocol}/{host}:{port}")
    if not is_loopback(endpoint):
        raise EndpointError(f"{host} is not a loopback address")
    return endpoint


def _parse(endpoint: Any) -> re.Match[str]:
    if not isinstance(endpoint, str):
        raise EndpointError(f"endpoint must be a string, got {type(endpoint).__name__}")
    match = _ENDPOINT.fullmatch(endpoint)
    if match is None or not 1 <= int(match["port"]) <= 65535:
        raise EndpointError(
            f"endpoint {endpoint[:120]!r} is not of the form PROTOCOL/HOST:PORT with a port in "
            "1..65535 (e.g. tcp/127.0.0.1:7447, tls/192.0.2.10:7447, tls/[::1]:7447)")
    return match


def split_endpoint(endpoint: str) -> tuple[str, str, int]:
    """``"tls/[::1]:7447#x=1"`` -> ``("tls", "::1", 7447)``. Raises :class:`EndpointError`."""
    match = _parse(endpoint)
    return match["proto"], match["v6"] or match["host"], int(match["port"])


def is_loopback(endpoint: str) -> bool:
    """Whether ``endpoint`` stays on this machine: a literal loopback address (127.0.0.0/8,
    ``::1``). Host names are not (``localhost`` may resolve anywhere), nor wildcards."""
    match = _parse(endpoint)
    try:
        return ipaddress.ip_address(match["v6"] or match["host"]).is_loopback
    except ValueError:
        return False


def check_endpoint(endpoint: Any, *, insecure: bool = False) -> str:
    """Return ``endpoint`` if it is well formed and either on loopback or secured (``tls/``,
    ``quic/``); a plain endpoint off loopback only with ``insecure``.

    Raises:
        EndpointError: malformed, or unsecured off loopback without ``insecure``.
    """
    match = _parse(endpoint)
    if is_loopback(endpoint) or match["proto"] in SECURE_PROTOCOLS or insecure:
        return endpoint
    secured = f"tls/{match['host'] or '[' + match['v6'] + ']'}:{match['port']}"
    raise EndpointError(
        f"endpoint {endpoint!r} is neither on loopback nor secured: use {secured} with a TLS config "
        "(--zenoh-config FILE; ersac-hil certs init makes one per role), or say --insecure")


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago (bind to port 0, then release).

    Another process may take it before you bind it: :class:`EmbeddedRouter` retries.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])
