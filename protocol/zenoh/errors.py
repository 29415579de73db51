"""Typed errors of the Zenoh contract.

Every failure to build a key or to encode/decode a payload raises one of these, never a bare
``KeyError``/``TypeError``. All of them are ``ValueError`` subclasses so callers that only
care about "bad input" can catch ``ValueError``.

Hierarchy::

    ValueError
    +-- KeySpaceError            invalid robot name / prefix / key chunk
    +-- PayloadError             anything wrong with a payload or selector parameters
        +-- MalformedPayload     not bytes, not UTF-8, not JSON, not an object, NaN/Infinity
        |   |                    literals, duplicate keys, too deeply nested
        |   +-- PayloadTooLarge  above MAX_PAYLOAD_BYTES
        +-- UnsupportedVersion   "v" is an integer this code does not speak
        +-- InvalidField         a field is missing, unexpected, of the wrong type or out of
                                 range; ``.field`` holds its dotted path ("result.cost_terms.damage")
"""

from __future__ import annotations

__all__ = [
    "KeySpaceError",
    "PayloadError",
    "MalformedPayload",
    "PayloadTooLarge",
    "UnsupportedVersion",
    "InvalidField",
]


class KeySpaceError(ValueError):
    """A robot name, prefix or key chunk that cannot be part of a Zenoh key expression."""


class PayloadError(ValueError):
    """Base class of every payload / selector-parameter validation error."""


class MalformedPayload(PayloadError):
    """The bytes are not a well-formed JSON object (or not bytes at all)."""


class PayloadTooLarge(MalformedPayload):
    """The payload exceeds the contract's size cap."""

    def __init__(self, size: int, limit: int) -> None:
        super().__init__(f"payload of {size} bytes exceeds the {limit}-byte limit")
        self.size = size
        self.limit = limit


class UnsupportedVersion(PayloadError):
    """The payload's ``"v"`` is a well-formed integer that this code does not support."""

    def __init__(self, version: int, supported: tuple[int, ...]) -> None:
        super().__init__(f"unsupported payload version {version}; supported: {list(supported)}")
        self.version = version
        self.supported = supported


class InvalidField(PayloadError):
    """A field is missing, unexpected, of the wrong type or out of range.

    Attributes:
        field: dotted path of the offending field, e.g. ``"theta[2]"`` or
            ``"result.telemetry.max_abs_pitch"``.
        reason: human-readable reason without the field name.
    """

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}" if field else reason)
        self.field = field
        self.reason = reason

    def prefixed(self, prefix: str) -> InvalidField:
        """The same error with ``prefix`` prepended to the field path (``""`` = the object
        itself, so the result names ``prefix``)."""
        if not self.field:
            return InvalidField(prefix, self.reason)
        joiner = "" if self.field.startswith("[") else "."
        return InvalidField(f"{prefix}{joiner}{self.field}", self.reason)
