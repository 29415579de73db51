"""What produces the episodes of an output directory: a fingerprint of the code behind them.

An episode's cost depends on the simulator (physics, scenarios, the MuJoCo model), the agent
(tasks, cost terms, controllers) and the task definitions (weights). ``fingerprint()`` hashes
the files of those packages as installed - the same files the stack's processes run, since
``reproduce`` starts them from this interpreter - and ``plan.json`` records it: an output
directory whose episodes came from other code is refused (episodes of an older simulator are
never mixed with new ones). Any change of those files counts, even one that does not change a
single episode: the check errs on the safe side.
"""
from __future__ import annotations

import hashlib
import importlib.util
from collections.abc import Callable
from pathlib import Path

__all__ = ["SOURCES", "CodeChanged", "fingerprint", "mismatch", "guard"]

#: The packages whose code makes an episode's outcome (the simulator is looked up, never imported).
SOURCES = ("firmware_sim", "ersac_hil.agent", "protocol.zenoh")


class CodeChanged(RuntimeError):
    """The simulator/agent code changed during a run (the message says which package)."""


def _root(package: str) -> Path | None:
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def fingerprint() -> dict[str, str]:
    """Per package of :data:`SOURCES`: sha256 (16 hex digits) over its files' relative paths
    and contents; ``"absent"`` for a package that is not installed."""
    out = {}
    for package in SOURCES:
        root = _root(package)
        if root is None:
            out[package] = "absent"
            continue
        h = hashlib.sha256()
        for f in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
        out[package] = h.hexdigest()[:16]
    return out


def mismatch(recorded: dict[str, str] | None, current: dict[str, str]) -> list[str]:
    """The packages whose code differs from ``recorded`` (none when nothing was recorded)."""
    if not recorded:
        return []
    return sorted(k for k in set(recorded) | set(current) if recorded.get(k) != current.get(k))


def guard(recorded: dict[str, str]) -> Callable[[], None]:
    """A check that raises ``CodeChanged`` once the code differs from ``recorded``."""
    def check() -> None:
        changed = mismatch(recorded, fingerprint())
        if changed:
            raise CodeChanged(f"the simulator/agent code changed during the run ({', '.join(changed)}): "
                              "its episodes must not be mixed; finish it with the code it started with, "
                              "or start again in another --out")
    return check
