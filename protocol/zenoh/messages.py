"""Versioned JSON envelope shared by every payload, and the error reply.

Wire form of every message: one JSON object (UTF-8, compact) whose first two members are the
envelope, followed by every field of the message (all fields are required; ``null`` where a
field is optional)::

    {"v": 1, "type": "kappa_command", "kappa": 0.5}

* ``v`` - payload schema version (:data:`VERSION`); an integer not in
  :data:`SUPPORTED_VERSIONS` raises :class:`UnsupportedVersion`.
* ``type`` - the message type (``Message.TYPE``); decoding with the wrong class raises
  :class:`InvalidField` on ``"type"``.

Messages are frozen msgspec Structs (``protocol.zenoh.fields.Record``): field types carry their
constraints, unknown fields are refused, and a message built in code passes the same checks
as one decoded from the wire.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Literal, Self

from msgspec import Meta

from . import codec
from .codec import FrozenMap
from .errors import InvalidField, UnsupportedVersion
from .fields import Record, anchored, field_types, unwrap, convert
from .keys import CHUNK_PATTERN

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
    if expected_type is not None and kind != expected_type:
        raise InvalidField("type", f"expected {expected_type!r}, got {str(kind)[:80]!r}")
    if expected_type is None and (not isinstance(kind, str) or kind not in _REGISTRY):
        raise InvalidField("type", f"unknown message type {str(kind)[:80]!r}; expected one of {list(_REGISTRY)}")
    return kind


def _require_all(obj: Any, cls: type, path: str) -> None:
    """Every field of ``cls`` (and of nested records) is present: on the wire no field is
    optional, even those with a default in code - except those a later revision of the same
    version added (``WIRE_OPTIONAL``), so that older senders stay valid."""
    if not isinstance(obj, Mapping):
        return  # msgspec names the wrong kind
    hints = field_types(cls)
    optional = getattr(cls, "WIRE_OPTIONAL", frozenset())
    for name in cls.__struct_fields__:
        where = f"{path}.{name}" if path else name
        if name not in obj and name not in optional:
            raise InvalidField(where, f"missing field of {getattr(cls, 'TYPE', cls.__name__)!r}")
        sub = unwrap(hints[name])
        if isinstance(sub, type) and issubclass(sub, Record):
            _require_all(obj.get(name), sub, where)
        elif getattr(sub, "__origin__", None) is tuple and isinstance(obj.get(name), list):
            item = unwrap(sub.__args__[0])
            if isinstance(item, type) and issubclass(item, Record):
                for i, value in enumerate(obj[name]):
                    _require_all(value, item, f"{where}[{i}]")


class Message(Record, frozen=True):
    """Base of every payload. Subclasses set ``TYPE`` (the wire ``type``) and may list in
    ``WIRE_OPTIONAL`` fields added after the first revision of the version (absent: default)."""

    TYPE: ClassVar[str] = ""
    WIRE_OPTIONAL: ClassVar[frozenset[str]] = frozenset()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.TYPE:
            if cls.TYPE in _REGISTRY:
                raise TypeError(f"duplicate message type {cls.TYPE!r}")
            _REGISTRY[cls.TYPE] = cls

    def to_obj(self) -> dict[str, Any]:
        """The message's fields as a JSON-ready ``dict`` (no envelope)."""
        return self._builtins()

    def to_json(self) -> bytes:
        """Encode with the ``{"v", "type"}`` envelope. Raises ``PayloadTooLarge``."""
        body = codec.dumps(self)
        head = b'{"v":%d,"type":"%s"' % (VERSION, self.TYPE.encode())
        data = head + (b"," + body[1:] if len(body) > 2 else b"}")
        if len(data) > codec.MAX_PAYLOAD_BYTES:
            raise codec.PayloadTooLarge(len(data), codec.MAX_PAYLOAD_BYTES)
        return data

    @classmethod
    def from_obj(cls, obj: Any) -> Self:
        """Build from a ``dict`` holding exactly the message's fields (no envelope).

        Raises:
            InvalidField: not an object, missing or unexpected field, invalid value.
        """
        if not isinstance(obj, Mapping):
            raise InvalidField("", f"expected a {cls.TYPE!r} object, got {type(obj).__name__}")
        _require_all(obj, cls, "")
        return convert(obj, cls)

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


class ErrorReply(Message, frozen=True):
    """Payload of every ``query.reply_err``.

    Attributes:
        code: one of :data:`ERROR_CODES`.
        reason: human-readable explanation (1..4096 characters).
    """

    TYPE: ClassVar[str] = "error"

    code: Literal[ERROR_CODES]  # type: ignore[valid-type]
    reason: Annotated[str, Meta(min_length=1, max_length=4096)]

    @classmethod
    def from_exception(cls, exc: BaseException, code: str = "invalid_request") -> ErrorReply:
        """An error reply carrying ``str(exc)`` (truncated to fit)."""
        reason = str(exc) or type(exc).__name__
        return cls(code, reason[:4096])



# -- safety: the e-stop and the agent's own state ---------------------------------------------
#: What the agent is doing (``AgentState.phase``).
AGENT_PHASES: tuple[str, ...] = (
    "ready",  # serves the next episode at once
    "waiting_for_go",  # no test bench: the next episode waits for a person's go (``ersac-hil go``)
    "running",  # an episode is running
    "stopped",  # e-stop engaged: every axis in quick stop, no episode until released
    "uncommissioned",  # a physical bus without a passed ``ersac-hil commission``: no episode
)
#: How the agent paces SYNC (``AgentState.pacing``).
PACINGS: tuple[str, ...] = ("realtime", "lockstep")
#: What the agent knows about its bus (``AgentState.bench``).
BENCHES: tuple[str, ...] = ("simulated", "real")


class EstopCommand(Message, frozen=True):
    """Payload of a put on ``agent/estop`` (operator role only).

    Attributes:
        engage: ``true`` stops every axis (quick stop) and ends the running episode as
            ``stopped``; ``false`` releases a stop (the robot then waits for go again where
            there is no test bench).
        reason: who stopped it and why (free text, may be empty).
    """

    TYPE: ClassVar[str] = "estop_command"

    engage: bool
    reason: Annotated[str, Meta(max_length=4096)] = ""


class AgentState(Message, frozen=True):
    """Reply of the ``agent/state`` queryable.

    Attributes:
        robot: the robot's name.
        phase: one of :data:`AGENT_PHASES`.
        pacing: one of :data:`PACINGS`: how the next episode paces SYNC.
        bench: one of :data:`BENCHES`: ``simulated`` while the simulator's test-bench node is
            heard on the bus (and the bus is not a physical SocketCAN channel), else ``real``.
        episodes: episodes run since the agent started.
        detail: why the agent is in this phase (the e-stop's reason, what it waits for).
    """

    TYPE: ClassVar[str] = "agent_state"

    robot: Annotated[str, Meta(pattern=anchored(CHUNK_PATTERN))]
    phase: Literal[AGENT_PHASES]  # type: ignore[valid-type]
    pacing: Literal[PACINGS]  # type: ignore[valid-type]
    bench: Literal[BENCHES]  # type: ignore[valid-type]
    episodes: Annotated[int, Meta(ge=0, le=2**53)]
    detail: Annotated[str, Meta(max_length=4096)] = ""
