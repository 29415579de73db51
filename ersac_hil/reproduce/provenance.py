"""What produces the episodes of an output directory: a fingerprint of the code behind them.

An episode's cost depends on the simulator (physics, scenarios, the MuJoCo model), the agent
(tasks, cost terms, controllers) and the task definitions (weights): :data:`SOURCES`. A
learning run depends on those and on the learner that picks its policies: the ERSAC learner,
the critic and the daemon's engine around them (:data:`LEARNING`); a landscape or test trial
(a fixed policy) does not. ``fingerprint()`` hashes the files of those packages/modules as
installed - the same files the stack's processes run, since ``reproduce`` starts them from
this interpreter - and ``plan.json`` records them (``planfile``): an output directory whose
episodes came from other episode code is refused, a learning run made by other learner code
is refused, while the trials stay reusable. Any change of those files counts, even one that
does not change a single episode: the check errs on the safe side.
"""
from __future__ import annotations

import hashlib
import importlib.util
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["SOURCES", "LEARNING", "CodeChanged", "fingerprint", "mismatch", "guard"]

#: The packages whose code makes an episode's outcome (the simulator is looked up, never imported).
SOURCES = ("firmware_sim", "ersac_hil.agent", "protocol.zenoh")
#: The code that makes a learning run's policies (on top of :data:`SOURCES`).
LEARNING = ("ersac_hil.learner", "ersac_hil.critic", "ersac_hil.daemon.engine")


class CodeChanged(RuntimeError):
    """The simulator/agent code changed during a run (the message says which package)."""


def _files(name: str) -> tuple[Path, list[Path]] | None:
    """(root, files) of a package (its tree) or a module (its one file); ``None`` if absent."""
    spec = importlib.util.find_spec(name)
    if spec is None:
        return None
    if spec.submodule_search_locations:
        root = Path(next(iter(spec.submodule_search_locations)))
        return root, sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    if spec.origin is None or not Path(spec.origin).is_file():
        return None
    return Path(spec.origin).parent, [Path(spec.origin)]


def fingerprint(names: Sequence[str] = SOURCES) -> dict[str, str]:
    """Per package or module of ``names`` (default :data:`SOURCES`): sha256 (16 hex digits)
    over its files' relative paths and contents; ``"absent"`` for one that is not installed."""
    out = {}
    for name in names:
        found = _files(name)
        if found is None:
            out[name] = "absent"
            continue
        root, files = found
        h = hashlib.sha256()
        for f in files:
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
        out[name] = h.hexdigest()[:16]
    return out


def mismatch(recorded: dict[str, str] | None, current: dict[str, str]) -> list[str]:
    """The packages whose code differs from ``recorded`` (none when nothing was recorded)."""
    if not recorded:
        return []
    return sorted(k for k in set(recorded) | set(current) if recorded.get(k) != current.get(k))


def guard(recorded: dict[str, str]) -> Callable[[], None]:
    """A check that raises ``CodeChanged`` once the code of the packages/modules in
    ``recorded`` differs from it."""
    def check() -> None:
        changed = mismatch(recorded, fingerprint(tuple(recorded)))
        if changed:
            raise CodeChanged(f"the simulator/agent/learner code changed during the run ({', '.join(changed)}): "
                              "its episodes must not be mixed; finish it with the code it started with, "
                              "or start again in another --out")
    return check
