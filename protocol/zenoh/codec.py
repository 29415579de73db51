"""Strict JSON codec, field validators and selector-parameter parsing for the Zenoh contract.

Pure functions, standard library only. Every failure raises a
:class:`~protocol.zenoh.errors.PayloadError` subclass.

* :func:`dumps` / :func:`loads` - UTF-8 JSON with NaN/Infinity refused both ways, duplicate
  object keys refused, and a size cap of :data:`MAX_PAYLOAD_BYTES`.
* ``as_*`` validators - used by every message's ``__post_init__`` so that a message built in
  code and a message decoded from the wire pass exactly the same checks. They normalise
  (ints and numpy scalars to ``float``, sequences to ``tuple``, mappings to read-only,
  hashable, picklable :class:`FrozenMap` copies) and raise :class:`InvalidField` with the field path.
* :func:`parse_parameters` / :func:`format_parameters` - Zenoh selector parameters
  (``k1=v1;k2=v2``), plus strict number parsers for their values.
"""

from __future__ import annotations

import json
import math
import numbers
import re
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

from .errors import InvalidField, MalformedPayload, PayloadTooLarge

__all__ = [
    "FrozenMap",
    "MAX_PAYLOAD_BYTES",
    "MAX_PARAMETERS_CHARS",
    "NAME_PATTERN",
    "ID_PATTERN",
    "dumps",
    "loads",
    "as_float",
    "as_int",
    "as_bool",
    "as_str",
    "as_choice",
    "as_float_tuple",
    "as_mapping",
    "as_float_map",
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


def dumps(obj: Mapping[str, Any]) -> bytes:
    """Encode a JSON-ready mapping as compact ASCII JSON bytes.

    Raises:
        MalformedPayload: a value is not JSON-serialisable or not finite.
        PayloadTooLarge: the encoding exceeds :data:`MAX_PAYLOAD_BYTES`.
    """
    try:
        text = json.dumps(obj, allow_nan=False, separators=(",", ":"), ensure_ascii=True)
    except (TypeError, ValueError) as exc:
        raise MalformedPayload(f"cannot encode payload: {exc}") from exc
    data = text.encode("ascii")
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


# --------------------------------------------------------------------------- validators


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


def _kind(value: Any) -> str:
    return type(value).__name__


def as_float(
    value: Any,
    field: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
) -> float:
    """A finite real number (not bool) in ``[lo, hi]``, returned as ``float``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidField(field, f"expected a number, got {_kind(value)}")
    try:
        out = float(value)
    except (OverflowError, ValueError) as exc:
        raise InvalidField(field, f"not representable as a float: {exc}") from exc
    if not math.isfinite(out):
        raise InvalidField(field, f"must be finite, got {out!r}")
    if lo is not None and out < lo:
        raise InvalidField(field, f"{out!r} is below the minimum {lo!r}")
    if hi is not None and out > hi:
        raise InvalidField(field, f"{out!r} is above the maximum {hi!r}")
    return out


def as_int(value: Any, field: str, *, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not bool, not float) in ``[lo, hi]``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidField(field, f"expected an integer, got {_kind(value)}")
    out = int(value)
    if lo is not None and out < lo:
        raise InvalidField(field, f"{out} is below the minimum {lo}")
    if hi is not None and out > hi:
        raise InvalidField(field, f"{out} is above the maximum {hi}")
    return out


def as_bool(value: Any, field: str) -> bool:
    """A JSON boolean (``True``/``False`` only; no 0/1)."""
    if not isinstance(value, bool):
        raise InvalidField(field, f"expected a boolean, got {_kind(value)}")
    return value


def as_str(
    value: Any,
    field: str,
    *,
    pattern: re.Pattern[str] | None = None,
    max_len: int = 4096,
    allow_empty: bool = True,
) -> str:
    """A string of at most ``max_len`` characters, fully matching ``pattern`` if given."""
    if not isinstance(value, str):
        raise InvalidField(field, f"expected a string, got {_kind(value)}")
    if not value and not allow_empty:
        raise InvalidField(field, "must not be empty")
    if len(value) > max_len:
        raise InvalidField(field, f"longer than {max_len} characters")
    if pattern is not None and pattern.fullmatch(value) is None:
        raise InvalidField(field, f"{value[:80]!r} does not match {pattern.pattern!r}")
    return value


def as_choice(value: Any, field: str, choices: Iterable[str]) -> str:
    """One of a fixed set of strings."""
    options = tuple(choices)
    if not isinstance(value, str) or value not in options:
        raise InvalidField(field, f"{value!r} is not one of {list(options)}")
    return value


def _as_list(value: Any, field: str) -> list[Any]:
    if isinstance(value, (list, tuple)):
        return list(value)
    tolist = getattr(value, "tolist", None)  # numpy arrays, without importing numpy
    if callable(tolist) and not isinstance(value, (str, bytes, Mapping)):
        out = tolist()
        if isinstance(out, list):
            return out
    raise InvalidField(field, f"expected a list, got {_kind(value)}")


def as_float_tuple(
    value: Any,
    field: str,
    *,
    length: int | None = None,
    min_len: int = 1,
    max_len: int = 64,
    lo: float | None = None,
    hi: float | None = None,
) -> tuple[float, ...]:
    """A list of finite floats (a list, tuple or 1-D numpy array), returned as a tuple."""
    items = _as_list(value, field)
    if length is not None and len(items) != length:
        raise InvalidField(field, f"expected {length} values, got {len(items)}")
    if not min_len <= len(items) <= max_len:
        raise InvalidField(field, f"expected {min_len}..{max_len} values, got {len(items)}")
    return tuple(as_float(x, f"{field}[{i}]", lo=lo, hi=hi) for i, x in enumerate(items))


def as_mapping(
    value: Any,
    field: str,
    item: Callable[[Any, str], _T],
    *,
    names: Iterable[str] | None = None,
    required: Iterable[str] = (),
    max_items: int = 256,
    allow_empty: bool = True,
) -> Mapping[str, _T]:
    """A JSON object with snake-case keys, each value checked by ``item(value, path)``.

    Args:
        names: if given, the only keys allowed.
        required: keys that must be present.

    Returns:
        A read-only :class:`FrozenMap` copy, keys in their input order.
    """
    if not isinstance(value, Mapping):
        raise InvalidField(field, f"expected an object, got {_kind(value)}")
    if len(value) > max_items:
        raise InvalidField(field, f"more than {max_items} entries")
    if not value and not allow_empty:
        raise InvalidField(field, "must not be empty")
    allowed = None if names is None else tuple(names)
    out: dict[str, _T] = {}
    for key, raw in value.items():
        if not isinstance(key, str) or NAME_PATTERN.fullmatch(key) is None:
            raise InvalidField(field, f"key {key!r} is not a snake_case name")
        if allowed is not None and key not in allowed:
            raise InvalidField(f"{field}.{key}", f"unknown name; expected one of {list(allowed)}")
        out[key] = item(raw, f"{field}.{key}")
    missing = [name for name in required if name not in out]
    if missing:
        raise InvalidField(field, f"missing entries {missing}")
    return FrozenMap(out)


def as_float_map(
    value: Any,
    field: str,
    *,
    lo: float | None = None,
    names: Iterable[str] | None = None,
    required: Iterable[str] = (),
    allow_empty: bool = True,
) -> Mapping[str, float]:
    """A name -> finite float mapping (values ``>= lo`` if given)."""
    return as_mapping(
        value,
        field,
        lambda v, f: as_float(v, f, lo=lo),
        names=names,
        required=required,
        allow_empty=allow_empty,
    )


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


def parse_float(text: str, field: str, *, lo: float | None = None, hi: float | None = None) -> float:
    """A decimal number literal (no ``nan``/``inf``/``_``/spaces) as a finite float."""
    if not isinstance(text, str) or _FLOAT_TEXT.fullmatch(text) is None:
        raise InvalidField(field, f"{str(text)[:80]!r} is not a decimal number")
    return as_float(float(text), field, lo=lo, hi=hi)


def parse_int(text: str, field: str, *, lo: int | None = None, hi: int | None = None) -> int:
    """An unsigned decimal integer literal of at most 12 digits."""
    if not isinstance(text, str) or _INT_TEXT.fullmatch(text) is None:
        raise InvalidField(field, f"{str(text)[:80]!r} is not an unsigned integer")
    return as_int(int(text), field, lo=lo, hi=hi)


def parse_bool(text: str, field: str) -> bool:
    """``"true"`` or ``"false"`` (also ``""``, a bare key, meaning true)."""
    if text in ("true", ""):
        return True
    if text == "false":
        return False
    raise InvalidField(field, f"{str(text)[:80]!r} is not 'true' or 'false'")
