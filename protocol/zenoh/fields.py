"""Constrained field types (msgspec ``Meta``) and the typed-structure base of the contract.

Every payload is a :class:`Record`: a frozen ``msgspec.Struct`` that refuses unknown fields and
whose field types carry their constraints (``Annotated[float, Meta(ge=0)]``...), so that the
JSON Schema msgspec derives from them (``protocol.zenoh.jsonschema``) is the contract other
languages validate against. msgspec checks types and constraints when converting decoded
JSON; a record built in code goes through the same conversion in ``__post_init__``, so a record
that exists is valid however it was made. Checks that span fields (theta within the task's
bounds, ``F == J + kappa r``...) are each record's ``_check``.

Every failure is an :class:`~protocol.zenoh.errors.InvalidField` naming the offending field
by its dotted path (``"result.cost_terms.damage"``, ``"points[2].theta[0]"``).
"""

from __future__ import annotations

import contextvars
import functools
import math
import re
import sys
import types
import typing
from typing import Annotated, Any, TypeVar, Union

import msgspec
from msgspec import Meta
from msgspec.structs import force_setattr

from .codec import ID_PATTERN, NAME_PATTERN, FrozenMap, plain
from .errors import InvalidField

__all__ = [
    "Finite",
    "NonNegative",
    "Positive",
    "Name",
    "Id",
    "Count",
    "Text",
    "Record",
    "convert",
    "converting",
    "anchored",
    "unwrap",
    "field_types",
]

_MAX = sys.float_info.max
_FINITE_BOUND = repr(_MAX)  # as msgspec prints the bound: 1.7976931348623157e+308


def anchored(pattern: re.Pattern[str]) -> str:
    """A JSON-Schema (ECMA) and Python pattern matching exactly the strings ``pattern``
    fully matches (``$`` alone would also let a trailing newline through in Python)."""
    return f"^{pattern.pattern}$(?!\\n)"


#: A finite number (ints are accepted and become floats; booleans are not numbers).
Finite = Annotated[float, Meta(ge=-_MAX, le=_MAX)]
#: A finite number >= 0.
NonNegative = Annotated[float, Meta(ge=0.0, le=_MAX)]
#: A finite number > 0.
Positive = Annotated[float, Meta(gt=0.0, le=_MAX)]
#: snake_case names of cost terms, failure flags, telemetry figures, weights.
Name = Annotated[str, Meta(pattern=anchored(NAME_PATTERN))]
#: Ids of episodes and runs.
Id = Annotated[str, Meta(pattern=anchored(ID_PATTERN))]
#: A counter (0 .. 2**53, exact in every JSON implementation).
Count = Annotated[int, Meta(ge=0, le=2**53)]
#: Free text for humans.
Text = Annotated[str, Meta(max_length=4096)]

_T = TypeVar("_T")
_CONVERTING = contextvars.ContextVar("protocol_zenoh_converting", default=False)


def convert(obj: Any, tp: Any, field: str = "") -> Any:
    """``obj`` (JSON-like data, numpy values allowed) as the typed value ``tp``.

    Args:
        field: path prefix of the value, used in errors (``"theta"``).

    Raises:
        InvalidField: naming the offending field below ``field``.
    """
    token = _CONVERTING.set(True)
    try:
        data = msgspec.to_builtins(obj, enc_hook=plain)
        return msgspec.convert(data, tp, strict=True)
    except TypeError as exc:  # to_builtins: not a JSON value
        error = InvalidField("", str(exc))
    except msgspec.ValidationError as exc:
        error = _invalid_field(exc, data, tp)
    finally:
        _CONVERTING.reset(token)
    try:
        raise (error.prefixed(field) if field else error) from None
    finally:
        # no frame may keep the raised error: an error -> traceback -> frame -> error cycle
        # keeps every caller's frame alive until the garbage collector runs, and with them
        # e.g. a zenoh.Query, which then answers nothing until its querier times out
        del error


def converting() -> bool:
    """Whether the caller runs inside a msgspec conversion (a record's ``__post_init__``)."""
    return _CONVERTING.get()


class Record(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Base of every typed structure of the contract (see the module doc).

    Subclasses declare constrained fields and may override :meth:`_check` (cross-field
    checks, raising :class:`InvalidField`). Mapping fields hold read-only :class:`FrozenMap`
    copies, sequences are tuples, numbers are plain ``float``/``int`` (numpy inputs are
    converted), so records are hashable and picklable.
    """

    def __post_init__(self) -> None:
        if _CONVERTING.get():  # built by msgspec from checked data: normalise, then cross-check
            for name in self.__struct_fields__:
                value = getattr(self, name)
                if type(value) is dict:
                    force_setattr(self, name, FrozenMap(value))
            self._check()
            return
        checked = convert(self._builtins(), type(self))  # built in code: check like the wire
        for name in self.__struct_fields__:
            force_setattr(self, name, getattr(checked, name))

    def _builtins(self) -> dict[str, Any]:
        out = {}
        for name in self.__struct_fields__:
            try:
                out[name] = msgspec.to_builtins(getattr(self, name), enc_hook=plain)
            except TypeError as exc:
                raise InvalidField(name, str(exc)) from None
        return out

    def _check(self) -> None:
        """Cross-field checks; raise :class:`InvalidField`. Fields are already typed."""


# --------------------------------------------------------------------------- error paths

_WHERE = re.compile(r" - at `(?P<where>[^`]*)`(?: in `(?P<container>[^`]*)`)?$", re.S)
_FIELD_MSG = re.compile(r"^Object (?P<kind>contains unknown|missing required) field `(?P<name>.*)`$", re.S)
_STEP = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+|\.\.\.)\]")


def _parse_path(path: str) -> list[Any]:
    """``$.a.b[0].c[...]`` -> ``["a", "b", 0, "c", ...]``."""
    out: list[Any] = []
    for name, index in _STEP.findall(path[1:] if path.startswith("$") else path):
        out.append(name if name else (Ellipsis if index == "..." else int(index)))
    return out


def _dotted(parts: list[Any]) -> str:
    text = ""
    for p in parts:
        text += f"[{p}]" if isinstance(p, int) else (f".{p}" if text else str(p))
    return text


def unwrap(tp: Any) -> Any:
    """The type under ``Annotated`` and ``X | None``."""
    while True:
        origin = typing.get_origin(tp)
        if origin is Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) != 1:
                return tp
            tp = args[0]
        else:
            return tp


@functools.cache
def field_types(cls: type) -> dict[str, Any]:
    """A record's field annotations, resolved, ``Annotated`` constraints kept."""
    return typing.get_type_hints(cls, include_extras=True)


def _step(tp: Any, part: Any) -> Any:
    tp = unwrap(tp)
    if isinstance(part, str):
        return field_types(tp)[part]
    args = typing.get_args(tp)
    return args[1] if part is Ellipsis else args[0]  # dict value / tuple[X, ...] item


def _invalid_field(exc: msgspec.ValidationError, data: Any, tp: Any) -> InvalidField:
    """Translate msgspec's error into :class:`InvalidField` with a dotted field path."""
    try:
        return _translate(exc, data, tp)
    except Exception:  # noqa: BLE001 - a message shape we do not know: keep msgspec's text
        return InvalidField("", str(exc))


def _translate(exc: msgspec.ValidationError, data: Any, tp: Any) -> InvalidField:
    text = str(exc)
    match = _WHERE.search(text)
    message = text[: match.start()] if match else text
    in_key = bool(match and match.group("container"))
    parts = _parse_path(match.group("container") if in_key else match.group("where")) if match else []
    cause = exc.__cause__
    # walk the data along the path, resolving dict entries ("[...]") to the offending key
    value, vtype = data, tp
    for i, part in enumerate(parts):
        vtype_next = _step(vtype, part)
        if part is Ellipsis:
            key = _first_bad(value, vtype_next, keys=False)
            parts[i] = key
            value = value[key]
        else:
            value = value[part]
        vtype = vtype_next
    if isinstance(cause, InvalidField):
        return cause.prefixed(_dotted(parts)) if parts else cause
    found = _FIELD_MSG.match(message)
    if found:
        name = found.group("name")
        parts.append(name)
        what = "unexpected field" if found.group("kind") == "contains unknown" else "missing field"
        owner = getattr(unwrap(vtype), "TYPE", "")
        return InvalidField(_dotted(parts), f"{what} of {owner!r}" if owner else what)
    if in_key:
        key_type = typing.get_args(unwrap(vtype))[0]
        key = _first_bad(value, key_type, keys=True)
        if isinstance(key, str) and NAME_PATTERN.fullmatch(key):
            parts.append(key)
            return InvalidField(_dotted(parts), _reason(message, key, key_type, "name"))
        return InvalidField(_dotted(parts), f"key {str(key)[:80]!r} is not a snake_case name"
                            if unwrap(key_type) is str else f"key {str(key)[:80]!r}: {message}")
    name = next((p for p in reversed(parts) if isinstance(p, str)), "value")
    return InvalidField(_dotted(parts), _reason(message, value, vtype, name))


def _first_bad(mapping: dict[str, Any], tp: Any, keys: bool) -> Any:
    for key, value in mapping.items():
        try:
            msgspec.convert(key if keys else value, tp, strict=True)
        except msgspec.ValidationError:
            return key
    raise LookupError("no offending entry")  # pragma: no cover - msgspec said there is one


_BOUND = re.compile(r"^Expected `[^`]+` (?P<op>>=|>|<=|<) (?P<bound>\S+)$")
_LENGTH = re.compile(r"^Expected `(?P<kind>[^`]+)` of length (?P<op>>=|<=) (?P<n>\d+)$")
_REGEX = re.compile(r"^Expected `str` matching regex (?P<pattern>.*)$", re.S)
_OPS = {">=": "below the minimum", ">": "not above", "<=": "above the maximum", "<": "not below"}


def _reason(message: str, value: Any, tp: Any, name: str) -> str:
    """msgspec's message, said the way a person reads it (with the value received)."""
    shown = repr(value) if not isinstance(value, (dict, list)) else type(value).__name__
    shown = shown[:80]
    if _FINITE_BOUND in message or (isinstance(value, float) and not math.isfinite(value)):
        return f"must be a finite number, got {shown}"
    if message.startswith("Invalid enum value"):
        choices = list(typing.get_args(unwrap(tp)))
        return f"unknown {name} {shown}; expected one of {choices}"
    if found := _BOUND.match(message):
        return f"{shown} is {_OPS[found['op']]} {found['bound']}"
    if found := _LENGTH.match(message):
        size, n = len(value), int(found["n"])
        unit = "characters" if found["kind"] == "str" else "entries"
        if found["op"] == ">=":
            return "must not be empty" if n == 1 else f"expected at least {n} {unit}, got {size}"
        return f"expected at most {n} {unit}, got {size}"
    if found := _REGEX.match(message):
        return f"{shown} does not match {found['pattern']}"
    owner = getattr(unwrap(tp), "TYPE", "")
    if owner and message.startswith("Expected `object`"):
        return f"{message}: expected a {owner!r} object"
    if "got `" not in message:
        return f"{message}, got {shown}"
    return message
