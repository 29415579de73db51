"""The record that commissioning passed: a fingerprint of the description and of the robot.

``fingerprint = sha256(description file bytes, then every robot node's identity)`` (node-id,
0x1000, 0x1018 vendor, product, revision, serial, in node-id order). Edit the description or
swap a drive (another serial number) and the fingerprint changes: commissioning must pass again.

Where the record lives (``record_path``): ``--commission-record FILE`` if given, else
``$ERSAC_HIL_STATE_DIR/commissioning/<description>.json``, else ``$STATE_DIRECTORY`` (what a
systemd unit's ``StateDirectory=`` sets), else ``$XDG_STATE_HOME/ersac-hil``, else
``~/.local/state/ersac-hil``; ``<description>`` is the description's name.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Iterable
from pathlib import Path

from ersac_hil.commission.scan import Identity
from protocol.robot import RobotDescription


def state_dir() -> Path:
    for var in ("ERSAC_HIL_STATE_DIR", "STATE_DIRECTORY"):
        value = os.environ.get(var)
        if value:
            return Path(value.split(":")[0])
    xdg = os.environ.get("XDG_STATE_HOME")
    return Path(xdg) / "ersac-hil" if xdg else Path.home() / ".local" / "state" / "ersac-hil"


def record_path(description: RobotDescription, override: str | os.PathLike | None = None) -> Path:
    return Path(override) if override else state_dir() / "commissioning" / f"{description.name}.json"


def description_bytes(description: RobotDescription) -> bytes:
    """The description file as it is now (a shipped one: its packaged file)."""
    if description.source and Path(description.source).is_file():
        return Path(description.source).read_bytes()
    return repr(description).encode()


def fingerprint(description: RobotDescription, identities: Iterable[Identity]) -> str:
    h = hashlib.sha256(description_bytes(description))
    for ident in sorted(identities, key=lambda i: i.node_id):
        h.update(json.dumps(ident.as_list()).encode())
    return h.hexdigest()


def write_record(path: Path, description: RobotDescription, bus: str, value: str,
                 identities: Iterable[Identity]) -> None:
    """Write the record atomically (a half-written record must never pass)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    body = {"description": description.name, "source": description.source, "bus": bus,
            "fingerprint": value, "passed_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "nodes": [i.as_list() for i in identities]}
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(body, indent=1) + "\n")
    os.replace(tmp, path)


def recorded(path: Path) -> str | None:
    """The fingerprint a record holds (``None``: no record, or not a readable one)."""
    try:
        return str(json.loads(path.read_text())["fingerprint"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
