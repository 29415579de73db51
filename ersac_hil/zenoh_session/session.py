"""Opening sessions: the one checked opener, and a scope that closes what it opened."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import zenoh

from .config import check_config, json_at
from .errors import ZenohSessionError, zenoh_reason

__all__ = ["open_session", "session_scope"]


def open_session(config: zenoh.Config, *, insecure: bool = False) -> zenoh.Session:
    """Check ``config`` (:func:`check_config`) and open a session. The caller closes it.

    Raises:
        ZenohConfigError: the config breaks a rule of :func:`check_config`.
        ZenohSessionError: Zenoh failed to open (port in use, nothing to connect to, TLS
            handshake refused...).
    """
    check_config(config, insecure=insecure)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        endpoints = json_at(config, "listen/endpoints") + json_at(config, "connect/endpoints")
        raise ZenohSessionError(f"cannot open a zenoh session on {endpoints}: {zenoh_reason(exc)}") from exc


@contextmanager
def session_scope(config: zenoh.Config, *, insecure: bool = False) -> Iterator[zenoh.Session]:
    """Open a session for the ``with`` block and close it on exit (closing undeclares every
    subscriber, queryable and token it declared)."""
    session = open_session(config, insecure=insecure)
    try:
        yield session
    finally:
        session.close()
