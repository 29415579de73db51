"""Versioned JSON envelope shared by every payload, and the error reply.

Wire form of every message: one JSON object (UTF-8, compact) whose first two members are the
envelope, followed by every field of the message (all fields are required; ``null`` where a
field is optional)::

    {"v": 1, "type": "kappa_command", "kappa": 0.5}

* ``v`` - payload schema version (:data:`VERSION`); an integer not in
  :data:`SUPPORTED_VERSIONS` raises :class:`UnsupportedVersion`.
* ``type`` - the message type (``Message.TYPE``); decoding with the wrong class raises
  :class:`InvalidField` on ``"type"``.

Messages are frozen dataclasses. Their ``__post_init__`` validates and normalises every field,
so a message that exists is valid whether it was built in code or decoded from the wire.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Iterator, Self

from . import codec
from .codec import FrozenMap, as_choice, as_str
from .errors import InvalidField, UnsupportedVersion

__all__ = [
    "VERSION",
    "SUPPORTED_VERSIONS",
    "ERROR_CODES",
    "Message",
    "ErrorReply",
    "decode",
    "message_types",
]

#: Schema version written by this code.
VERSION = 1
#: Schema versions this code decodes.
SUPPORTED_VERSIONS: tuple[int, ...] = (1,)

_REGISTRY: dict[str, type[Message]] = {}


@contextmanager
def field_prefix(prefix: str) -> Iterator[None]:
    """Re-raise :class:`InvalidField` from the block with ``prefix`` prepended to its path."""
    try:
        yield
    except InvalidField as exc:
        raise exc.prefixed(prefix) from None


def _plain(value: Any) -> Any:
    if isinstance(value, Message):
        return value.to_obj()
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


def check_envelope(obj: Mapping[str, Any], expected_type: str | None = None) -> str:
    """Check ``v`` and ``type`` of a decoded object; return its type name."""
    if "v" not in obj:
        raise InvalidField("v", "missing payload version")
    version = obj["v"]
    if isinstance(version, bool) or not isinstance(version, int):
        raise InvalidField("v", f"expected an integer version, got {type(version).__name__}")
    if version not in SUPPORTED_VERSIONS:
        raise UnsupportedVersion(version, SUPPORTED_VERSIONS)
    if "type" not in obj:
        raise InvalidField("type", "missing message type")
    kind = obj["type"]
    if expected_type is not None:
        if kind != expected_type:
            raise InvalidField("type", f"expected {expected_type!r}, got {str(kind)[:80]!r}")
    else:
        as_choice(kind, "type", _REGISTRY)
    return kind


class Message:
    """Base of every payload dataclass.

    Subclasses set ``TYPE`` (the wire ``type``) and, for fields holding other messages,
    ``NESTED = {"field": MessageClass}`` or ``{"field": (MessageClass,)}`` for a list.
    """

    TYPE: ClassVar[str] = ""
    NESTED: ClassVar[Mapping[str, type[Message] | tuple[type[Message]]]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.TYPE:
            if cls.TYPE in _REGISTRY:
                raise TypeError(f"duplicate message type {cls.TYPE!r}")
            _REGISTRY[cls.TYPE] = cls

    def to_obj(self) -> dict[str, Any]:
        """The message's fields as a JSON-ready ``dict`` (no envelope)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}  # type: ignore[arg-type]

    def to_json(self) -> bytes:
        """Encode with the ``{"v", "type"}`` envelope. Raises ``PayloadTooLarge``."""
        return codec.dumps({"v": VERSION, "type": self.TYPE, **self.to_obj()})

    @classmethod
    def from_obj(cls, obj: Any) -> Self:
        """Build from a ``dict`` holding exactly the message's fields (no envelope).

        Raises:
            InvalidField: not an object, missing or unexpected field, invalid value.
        """
        if not isinstance(obj, Mapping):
            raise InvalidField("", f"expected a {cls.TYPE!r} object, got {type(obj).__name__}")
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        for key in obj:
            if key not in names:
                raise InvalidField(str(key)[:80], f"unexpected field for {cls.TYPE!r}")
        for name in names:
            if name not in obj:
                raise InvalidField(name, f"missing field of {cls.TYPE!r}")
        kwargs: dict[str, Any] = {}
        for name in names:
            value = obj[name]
            spec = cls.NESTED.get(name)
            if spec is None:
                kwargs[name] = value
            elif isinstance(spec, tuple):
                if not isinstance(value, list):
                    raise InvalidField(name, f"expected a list, got {type(value).__name__}")
                items = []
                for i, item in enumerate(value):
                    with field_prefix(f"{name}[{i}]"):
                        items.append(spec[0].from_obj(item))
                kwargs[name] = tuple(items)
            else:
                with field_prefix(name):
                    kwargs[name] = spec.from_obj(value)
        return cls(**kwargs)

    @classmethod
    def from_json(cls, data: Any) -> Self:
        """Decode payload bytes (``bytes``, ``str``, ``zenoh.ZBytes``...) into this message.

        Raises:
            MalformedPayload, PayloadTooLarge, UnsupportedVersion, InvalidField.
        """
        obj = codec.loads(data)
        check_envelope(obj, cls.TYPE)
        return cls.from_obj({k: v for k, v in obj.items() if k not in ("v", "type")})


def decode(data: Any) -> Message:
    """Decode any known message, dispatching on its ``type`` (for monitors and tools)."""
    obj = codec.loads(data)
    kind = check_envelope(obj)
    return _REGISTRY[kind].from_obj({k: v for k, v in obj.items() if k not in ("v", "type")})


def message_types() -> Mapping[str, type[Message]]:
    """Every registered message class by wire ``type``."""
    return FrozenMap(_REGISTRY)


def set_field(obj: Any, name: str, value: Any) -> None:
    """Assign a normalised value in a frozen dataclass's ``__post_init__``."""
    object.__setattr__(obj, name, value)


#: Machine-readable ``ErrorReply.code`` values.
ERROR_CODES: tuple[str, ...] = (
    "invalid_request",  # the payload or selector parameters failed validation
    "unknown_task",  # the task is valid in the contract but not served here
    "busy",  # an episode / selection is already running
    "unavailable",  # not ready (no run, no data, hardware not up)
    "fault",  # the hardware side failed before an episode could start
    "timeout",  # the work did not finish in time
    "internal",  # a bug: the reason says what
)


@dataclass(frozen=True)
class ErrorReply(Message):
    """Payload of every ``query.reply_err``.

    Attributes:
        code: one of :data:`ERROR_CODES`.
        reason: human-readable explanation (1..4096 characters).
    """

    TYPE = "error"

    code: str
    reason: str

    def __post_init__(self) -> None:
        as_choice(self.code, "code", ERROR_CODES)
        as_str(self.reason, "reason", max_len=4096, allow_empty=False)

    @classmethod
    def from_exception(cls, exc: BaseException, code: str = "invalid_request") -> ErrorReply:
        """An error reply carrying ``str(exc)`` (truncated to fit)."""
        reason = str(exc) or type(exc).__name__
        return cls(code, reason[:4096])
