"""Strict JSON framing, the read-only mapping of messages and selector-parameter parsing.

Pure functions. Every failure raises a :class:`~protocol.zenoh.errors.PayloadError` subclass.

* :func:`dumps` / :func:`loads` - UTF-8 JSON with NaN/Infinity refused both ways, duplicate
  object keys refused, nesting depth and size capped (:data:`MAX_PAYLOAD_BYTES`). Field types
  and constraints are checked afterwards by msgspec (``protocol.zenoh.fields``).
* :class:`FrozenMap` - the read-only, hashable, picklable mapping message fields hold.
* :func:`parse_parameters` / :func:`format_parameters` - Zenoh selector parameters
  (``k1=v1;k2=v2``), plus strict number parsers for their values.
"""

from __future__ import annotations

import json
import os
import math
import re
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

import msgspec

from .errors import InvalidField, MalformedPayload, PayloadTooLarge

__all__ = [
    "FrozenMap",
    "MAX_PAYLOAD_BYTES",
    "MAX_PARAMETERS_CHARS",
    "NAME_PATTERN",
    "ID_PATTERN",
    "dumps",
    "loads",
    "parse_parameters",
    "format_parameters",
    "parse_float",
    "parse_int",
    "parse_bool",
    "format_float",
]

#: Hard cap on an encoded payload (bytes). Decoding checks it before parsing.
MAX_PAYLOAD_BYTES = 1 << 20
#: Hard cap on a selector's parameter string (characters).
MAX_PARAMETERS_CHARS = 64 * 1024
#: Names of cost terms, failure flags, telemetry figures, weights: lower snake case.
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_]{0,63}")
#: Identifiers of episodes and runs (UUIDs, timestamps, counters all fit).
ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.:\-]{0,127}")

_MAX_DEPTH = 32
_T = TypeVar("_T")


class FrozenMap(Mapping[str, _T]):
    """An immutable, hashable, picklable ``str -> value`` mapping (keeps insertion order).

    Compares equal to any mapping with the same items, e.g. a plain ``dict``.
    """

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[str, _T] | Iterable[tuple[str, _T]] = ()) -> None:
        object.__setattr__(self, "_data", dict(data))

    def __getitem__(self, key: str) -> _T:
        return self._data[key]

    def __iter__(self):  # noqa: ANN204
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        return hash(frozenset(self._data.items()))

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("FrozenMap is immutable")

    def __reduce__(self):  # noqa: ANN204
        return (FrozenMap, (self._data,))

    def __repr__(self) -> str:
        return f"FrozenMap({self._data!r})"


def plain(obj: Any) -> Any:
    """msgspec ``enc_hook``: read-only mappings as dicts, numpy arrays and scalars as lists
    and Python numbers (via ``tolist``, without importing numpy)."""
    if isinstance(obj, Mapping):
        return dict(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    tolist = getattr(obj, "tolist", None)
    if callable(tolist) and not isinstance(obj, (str, bytes)):
        return tolist()
    raise TypeError(f"a {type(obj).__name__} is not a JSON value")


_ENCODER = msgspec.json.Encoder(enc_hook=plain)


# --------------------------------------------------------------------------- JSON


def _refuse_constant(name: str) -> Any:
    raise MalformedPayload(f"non-finite number literal {name!r} is not allowed")


def _unique_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj: dict[str, Any] = {}
    for key, value in pairs:
        if key in obj:
            raise MalformedPayload(f"duplicate object key {key!r}")
        obj[key] = value
    return obj


def _depth(value: Any, limit: int) -> None:
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if depth > limit:
            raise MalformedPayload(f"JSON nested deeper than {limit} levels")
        if isinstance(item, dict):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, list):
            stack.extend((v, depth + 1) for v in item)


def dumps(obj: Any) -> bytes:
    """Encode a JSON-ready value (or a msgspec Struct) as compact UTF-8 JSON bytes.

    Values are expected to be validated (messages are): a non-finite float is written as
    ``null`` by msgspec, never as a ``NaN`` literal.

    Raises:
        MalformedPayload: a value is not JSON-serialisable.
        PayloadTooLarge: the encoding exceeds :data:`MAX_PAYLOAD_BYTES`.
    """
    try:
        data = _ENCODER.encode(obj)
    except (TypeError, ValueError, OverflowError) as exc:
        raise MalformedPayload(f"cannot encode payload: {exc}") from exc
    if len(data) > MAX_PAYLOAD_BYTES:
        raise PayloadTooLarge(len(data), MAX_PAYLOAD_BYTES)
    return data


def loads(data: Any) -> dict[str, Any]:
    """Decode payload bytes into a JSON object (``dict``).

    Accepts ``bytes``, ``bytearray``, ``memoryview``, ``str`` and objects with ``__bytes__``
    (such as ``zenoh.ZBytes``).

    Raises:
        MalformedPayload: not bytes-like, not UTF-8, not JSON, not an object, NaN/Infinity
            literals, duplicate keys, too deep.
        PayloadTooLarge: more than :data:`MAX_PAYLOAD_BYTES`.
    """
    if isinstance(data, str):
        raw: bytes | str = data
        size = len(data.encode("utf-8", "surrogatepass"))
    elif isinstance(data, (bytes, bytearray, memoryview)):
        raw = bytes(data)
        size = len(raw)
    elif hasattr(type(data), "__bytes__"):
        try:
            raw = bytes(data)
        except Exception as exc:  # noqa: BLE001 - foreign __bytes__ may raise anything
            raise MalformedPayload(f"cannot read payload bytes: {exc}") from exc
        size = len(raw)
    else:
        raise MalformedPayload(f"payload must be bytes, not {type(data).__name__}")
    if size > MAX_PAYLOAD_BYTES:
        raise PayloadTooLarge(size, MAX_PAYLOAD_BYTES)
    if isinstance(raw, bytes):
        try:
            raw = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MalformedPayload(f"payload is not UTF-8: {exc}") from exc
    try:
        obj = json.loads(raw, parse_constant=_refuse_constant, object_pairs_hook=_unique_object)
    except MalformedPayload:
        raise
    except RecursionError as exc:
        raise MalformedPayload("JSON nested too deeply") from exc
    except ValueError as exc:  # JSONDecodeError, int-digits limit
        raise MalformedPayload(f"payload is not valid JSON: {exc}") from exc
    if not isinstance(obj, dict):
        raise MalformedPayload(f"payload must be a JSON object, not {type(obj).__name__}")
    _depth(obj, _MAX_DEPTH)
    return obj


# --------------------------------------------------------------------------- selector parameters

_FLOAT_TEXT = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_INT_TEXT = re.compile(r"\d{1,12}")


def parse_parameters(params: Any, allowed: Iterable[str]) -> dict[str, str]:
    """Parse Zenoh selector parameters into a ``dict``.

    Args:
        params: ``"k1=v1;k2=v2"`` text, a ``Mapping[str, str]``, ``None`` (no parameters) or
            any object whose ``str()`` is such text (e.g. ``zenoh.Query.parameters``).
        allowed: the keys this query understands. Keys starting with ``_`` are reserved by
            Zenoh (``_time``, ``_anyke``) and skipped.

    Raises:
        InvalidField: unknown or duplicate key, over-long text.
    """
    accepted = tuple(allowed)
    pairs: list[tuple[str, str]]
    if params is None:
        pairs = []
    elif isinstance(params, Mapping):
        pairs = [(str(k), str(v)) for k, v in params.items()]
    else:
        text = params if isinstance(params, str) else str(params)
        if len(text) > MAX_PARAMETERS_CHARS:
            raise InvalidField("parameters", f"longer than {MAX_PARAMETERS_CHARS} characters")
        pairs = []
        for chunk in text.split(";"):
            if chunk:
                key, _, val = chunk.partition("=")
                pairs.append((key, val))
    out: dict[str, str] = {}
    for key, val in pairs:
        if key.startswith("_"):
            continue
        if key not in accepted:
            raise InvalidField(key or "parameters", f"unknown parameter; expected {list(accepted)}")
        if key in out:
            raise InvalidField(key, "given more than once")
        out[key] = val
    return out


def format_parameters(params: Mapping[str, str]) -> str:
    """``{"a": "1", "b": "x"}`` -> ``"a=1;b=x"`` (insertion order)."""
    return ";".join(f"{k}={v}" for k, v in params.items())


def format_float(value: float) -> str:
    """Shortest text that parses back to exactly ``value``."""
    return repr(float(value))


def parse_float(text: str, field: str) -> float:
    """A decimal number literal (no ``nan``/``inf``/``_``/spaces) as a finite float."""
    if not isinstance(text, str) or _FLOAT_TEXT.fullmatch(text) is None:
        raise InvalidField(field, f"{str(text)[:80]!r} is not a decimal number")
    value = float(text)
    if not math.isfinite(value):
        raise InvalidField(field, f"{text[:80]!r} is not a finite number")
    return value


def parse_int(text: str, field: str) -> int:
    """An unsigned decimal integer literal of at most 12 digits."""
    if not isinstance(text, str) or _INT_TEXT.fullmatch(text) is None:
        raise InvalidField(field, f"{str(text)[:80]!r} is not an unsigned integer")
    return int(text)


def parse_bool(text: str, field: str) -> bool:
    """``"true"`` or ``"false"`` (also ``""``, a bare key, meaning true)."""
    if text in ("true", ""):
        return True
    if text == "false":
        return False
    raise InvalidField(field, f"{str(text)[:80]!r} is not 'true' or 'false'")
