"""JSON Schema (draft 2020-12) of every payload, derived from the msgspec records.

Clients in other languages validate payloads against ``protocol/zenoh/schema/<type>.json``
(one file per message ``type``, envelope included). The schema checks shapes, types, ranges,
patterns and names; the few rules that span fields (theta within the bounds of *its* task,
``F == J + kappa r``, cost terms of *its* task, matching ids in nested request/result) are
checked by the records' ``_check`` and listed in ``docs/zenoh.md``.

Regenerate after changing a record (a test checks the committed files are current)::

    python -m protocol.zenoh.jsonschema            # writes protocol/zenoh/schema/
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import msgspec

from .messages import SUPPORTED_VERSIONS, VERSION, message_types

__all__ = ["SCHEMA_DIR", "payload_schema", "payload_schemas", "render", "write_schemas"]

#: Where the committed schema files live (shipped with the package).
SCHEMA_DIR = Path(__file__).resolve().parent / "schema"
_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def _require_everything(schema: dict[str, Any]) -> None:
    """On the wire every field is required, even those with a default in code, except those
    a later revision added (``WIRE_OPTIONAL``); descriptions keep the docstring's first
    paragraph."""
    optional = {cls.__name__: cls.WIRE_OPTIONAL for cls in message_types().values()}
    for name, definition in schema.get("$defs", {}).items():
        if "description" in definition:
            definition["description"] = " ".join(definition["description"].split("\n\n")[0].split())
        if definition.get("type") == "object" and "properties" in definition:
            skip = optional.get(name, frozenset())
            definition["required"] = [p for p in definition["properties"] if p not in skip]
            for prop_name, prop in definition["properties"].items():
                if prop_name not in skip:
                    prop.pop("default", None)


def payload_schema(message_type: str) -> dict[str, Any]:
    """The JSON Schema of one payload ``type`` (``"episode_request"``...), envelope included."""
    cls = message_types()[message_type]
    schema = msgspec.json.schema(cls)
    _require_everything(schema)
    defs = schema["$defs"]
    body = defs.pop(cls.__name__)
    properties = {
        "v": {"description": f"payload schema version (this schema: {VERSION})",
              "enum": list(SUPPORTED_VERSIONS)},
        "type": {"const": message_type},
        **body["properties"],
    }
    out: dict[str, Any] = {
        "$schema": _DIALECT,
        "$id": f"ersac-hil/protocol/zenoh/schema/{message_type}.json",
        "title": f"{message_type} ({cls.__name__})",
        "description": body.get("description", ""),
        "type": "object",
        "properties": properties,
        "required": [p for p in properties if p not in cls.WIRE_OPTIONAL],
        "additionalProperties": False,
    }
    if defs:
        out["$defs"] = defs
    return out


def payload_schemas() -> dict[str, dict[str, Any]]:
    """Every payload's schema by message ``type``."""
    return {name: payload_schema(name) for name in sorted(message_types())}


def render(schema: dict[str, Any]) -> str:
    """The committed text of a schema (stable: sorted keys, 2-space indent, final newline)."""
    return json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=True) + "\n"


def write_schemas(directory: Path = SCHEMA_DIR) -> list[Path]:
    """Write ``<type>.json`` for every payload into ``directory``; return the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, schema in payload_schemas().items():
        path = directory / f"{name}.json"
        path.write_text(render(schema))
        paths.append(path)
    return paths


if __name__ == "__main__":
    for written in write_schemas(Path(sys.argv[1]) if len(sys.argv) > 1 else SCHEMA_DIR):
        print(written)
