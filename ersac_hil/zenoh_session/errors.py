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
_JSON5_MESSAGE = re.compile(r'Json5Err\(Message \{ msg: "(.*?)", location: ', re.S)
_PARSER_DUMP = re.compile(r"-->\s*(\d+):(\d+).*\n\s*=\s*(.+?)\s*$", re.S)


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's error text made one readable line: without the Rust source locations it
    appends (`` at /.../x.rs:388.``: the build machine's paths tell a user nothing), a
    ``Json5Err(Message { msg: ... })`` as its message, and a json5 parser dump (source lines,
    carets) as where the parser stopped and what it expected there - the mistake is there or
    after it."""
    text = _RUST_SOURCE.sub("", str(exc)).strip()
    message = _JSON5_MESSAGE.search(text)
    if message:
        return message.group(1)
    dump = _PARSER_DUMP.search(text)
    if dump:
        line, column, expected = dump.groups()
        return (f"json5 syntax error: the parser stops at line {line}, column {column} ({expected}); "
                "the mistake is there or after it")
    return " ".join(text.split())
