"""Decode one Zenoh reply into the expected message, or say precisely why not.

Shared by the learner's agent link (``episode/run`` replies) and the control-plane clients
(``learner/*`` replies), so both read a reply the same way:

- ``reply.ok`` with a valid payload -> the message;
- ``reply.ok`` with an invalid payload -> :class:`MalformedReply`;
- ``reply.err`` with an ``ErrorReply`` payload -> :class:`ReplyRefused` (the replier's code);
- ``reply.err`` without one: Zenoh's own "Timeout" error -> :class:`ReplyTimeout`, anything
  else -> :class:`MalformedReply`.
"""
from __future__ import annotations

from typing import TypeVar

import zenoh

from protocol.zenoh import ErrorReply, Message, PayloadError

__all__ = ["ReplyFailure", "ReplyRefused", "ReplyTimeout", "MalformedReply", "decode_reply"]

_M = TypeVar("_M", bound=Message)


class ReplyFailure(Exception):
    """A reply that is not the expected message."""


class ReplyRefused(ReplyFailure):
    """The replier refused the request; ``error`` is its ``ErrorReply``."""

    def __init__(self, error: ErrorReply) -> None:
        super().__init__(f"{error.code}: {error.reason}")
        self.error = error


class ReplyTimeout(ReplyFailure):
    """Zenoh ended the query with its own timeout error (no replier answered in time)."""


class MalformedReply(ReplyFailure):
    """The payload does not decode (an ok reply that is not the message, or an error reply
    that is not an ``ErrorReply``)."""


def decode_reply(reply: zenoh.Reply, cls: type[_M]) -> _M:
    """The ``cls`` message of an ok ``reply``; raises a :class:`ReplyFailure` otherwise."""
    if reply.ok is not None:
        try:
            return cls.from_json(reply.ok.payload)
        except PayloadError as exc:
            raise MalformedReply(f"invalid {cls.TYPE}: {exc}") from None
    raw = reply.err.payload.to_bytes()
    try:
        error = ErrorReply.from_json(raw)
    except PayloadError:
        text = raw.decode("utf-8", "replace")[:500]
        if "timeout" in text.lower():
            raise ReplyTimeout(text) from None
        raise MalformedReply(f"reply_err without an ErrorReply: {text!r}") from None
    raise ReplyRefused(error)
