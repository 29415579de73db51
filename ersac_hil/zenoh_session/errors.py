"""The errors of opening Zenoh sessions, and Zenoh's own error text made readable."""
from __future__ import annotations

import re

__all__ = ["ZenohConfigError", "EndpointError", "ZenohSessionError", "zenoh_reason"]


class ZenohConfigError(ValueError):
    """A session configuration that this project refuses to use."""


class EndpointError(ZenohConfigError):
    """A malformed endpoint, or one off loopback that is not secured (without ``insecure``)."""


class ZenohSessionError(RuntimeError):
    """Zenoh could not open a session (port in use, no router to connect to...)."""


_RUST_SOURCE = re.compile(r"\s+at \S+\.rs:\d+\.?")


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's error text without the Rust source locations it appends (`` at /.../x.rs:388.``):
    the build machine's paths tell a user nothing."""
    return _RUST_SOURCE.sub("", str(exc)).strip()
