"""``plan.json`` of an output directory: what each experiment was made with (pure: dicts in,
dicts out; ``cli`` reads and writes the file).

It records, per experiment, the sizes it uses (:data:`FIELDS`); the fingerprint of the code
behind every episode (``model``: simulator, agent, tasks; ``provenance.SOURCES``); and per
learning run the fingerprint of the learner code that made it (``runs``; ``provenance.LEARNING``).

:func:`resolve` decides what a new invocation runs with, or refuses it (:class:`PlanConflict`):

* Sizes. A field the invocation does not set explicitly (``--seeds`` and ``--quick`` set
  every size; ``--lifting-interleave`` the lifting runs' learner option) is taken over from
  what the directory recorded for the experiments it runs, and from the fields they share with
  a recorded experiment (contexts continue lifting's first run: ``lifting_episodes``,
  ``test_trials``, ``lifting_interleave_every``); what is not recorded gets the defaults. So
  ``reproduce bracing --seeds 3`` then ``reproduce all`` continues bracing with 3 seeds and runs
  lifting and contexts with theirs. A recorded value of an explicitly set field must agree:
  ``reproduce all --seeds 5`` on a directory whose bracing has 3 seeds is refused. A field
  added after a directory was recorded reads as its :data:`LEGACY` value there.
* Episode code: any change refuses the directory (its trials and runs came from the old code).
* Learner code: a learning run of the invocation whose store exists and was made by other
  learner/critic code is refused (remove it to run it again: the trials stay and are reused);
  a run without a store is recorded with the current code. A run recorded by nothing (a
  directory older than this record) is taken as it is.
"""
from __future__ import annotations

import json
from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

from . import plan
from .plan import Sizes
from .provenance import mismatch
from .runner import RunSpec

__all__ = ["FIELDS", "INTERLEAVE", "LEGACY", "SIZE_FIELDS", "PlanConflict", "Resolved", "resolve", "runs_of"]

#: The sizes each experiment uses (contexts: the lifting run it continues, its test trials).
FIELDS: dict[str, tuple[str, ...]] = {
    "bracing": ("bracing_seeds", "bracing_episodes", "landscape_step", "landscape_episodes",
                "random_policies", "fig1_after", "last_window", "grid"),
    "lifting": ("lifting_seeds", "lifting_episodes", "lifting_stage", "test_trials", "lifting_interleave_every"),
    "contexts": ("lifting_episodes", "context_episodes", "test_trials", "lifting_interleave_every"),
}
#: The field of the lifting runs' learner option (``--lifting-interleave``); the others are sizes.
INTERLEAVE = "lifting_interleave_every"
SIZE_FIELDS = frozenset(f for fs in FIELDS.values() for f in fs) - {INTERLEAVE}
#: The value of a field in an experiment recorded before the field existed (what was run then).
LEGACY: dict[str, Any] = {INTERLEAVE: 0}


class PlanConflict(ValueError):
    """The invocation does not fit the output directory (a one-line reason)."""


@dataclass(frozen=True)
class Resolved:
    """The sizes to run with, whether they are the ``--quick`` ones for every experiment run,
    and the record to write as ``plan.json``."""

    sizes: Sizes
    quick: bool
    record: dict[str, Any]


def runs_of(experiment: str, sizes: Sizes) -> list[RunSpec]:
    """The learning runs ``experiment`` makes or continues."""
    if experiment == "bracing":
        return plan.bracing_runs(sizes)
    if experiment == "lifting":
        return plan.lifting_runs(sizes)
    return plan.lifting_runs(sizes)[:1] + [spec for _, spec in plan.context_runs(sizes)]


def _upgrade(recorded: Mapping[str, Any] | None) -> dict[str, Any]:
    """The record in the current layout; a directory made before per-experiment sizes had one
    size set for every experiment."""
    if not recorded:
        return {"experiments": {}, "model": None, "runs": {}}
    if "experiments" in recorded:
        experiments = {e: dict(v) for e, v in recorded["experiments"].items()}
        runs = dict(recorded.get("runs", {}))
    else:
        old = recorded.get("sizes", {})
        experiments = {e: {f: old[f] for f in fs if f in old} for e, fs in FIELDS.items()}
        runs = {}
    for e, values in experiments.items():
        values.update({f: v for f, v in LEGACY.items() if f in FIELDS.get(e, ()) and f not in values})
    return {"experiments": experiments, "model": recorded.get("model"), "runs": runs}


def _json(value: Any) -> Any:
    return json.loads(json.dumps(value))


def _sizes(values: Mapping[str, Any]) -> Sizes:
    return Sizes(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def _names(names: Sequence[str], sep: str = ", ") -> str:
    """The first three of ``names`` and how many more (a one-line message stays short)."""
    return sep.join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def resolve(recorded: Mapping[str, Any] | None, experiments: Sequence[str], requested: Sizes,
            explicit: Collection[str], model: Mapping[str, str], learning: Mapping[str, str],
            existing: Collection[str]) -> Resolved:
    """What ``experiments`` run with in a directory whose ``plan.json`` is ``recorded``.

    Args:
        recorded: the directory's ``plan.json`` (``None``: a new directory).
        experiments: the experiments of the invocation.
        requested: the sizes of its options (the defaults, ``--quick``'s, with ``--seeds``...).
        explicit: the fields its options set (the others are taken over where recorded).
        model, learning: the current fingerprints of the episode and the learner code.
        existing: the names of the learning runs whose store exists.

    Raises:
        PlanConflict: other episode code, sizes that disagree with the record, or an existing
            learning run made by other learner code.
    """
    rec = _upgrade(recorded)
    changed = mismatch(rec["model"], dict(model))
    if changed:
        raise PlanConflict(f"holds episodes of other simulator/agent code (changed: {', '.join(changed)}); "
                           "they must not be mixed with new ones: use another --out")
    known: dict[str, tuple[str, Any]] = {}
    for exp, sizes in rec["experiments"].items():
        for f, v in sizes.items():
            known.setdefault(f, (exp, v))
    values = _json(asdict(requested))
    used = [f for f in dict.fromkeys(f for e in experiments for f in FIELDS[e]) if f in known]
    clash = [f"{known[f][0]} has {f} {known[f][1]} (asked {values[f]})" for f in used
             if f in explicit and known[f][1] != values[f]]
    if clash:
        raise PlanConflict(f"holds experiments made with other sizes: {_names(clash, '; ')}; run without "
                           "--seeds/--quick/--lifting-interleave to continue them with theirs, or use another --out")
    values.update({f: known[f][1] for f in used if f not in explicit})
    sizes = _sizes(values)
    quick = all(values[f] == _json(asdict(plan.QUICK))[f] for e in experiments for f in FIELDS[e])
    runs = [spec.name for e in experiments for spec in runs_of(e, sizes)]
    stale = [n for n in dict.fromkeys(runs) if n in existing and mismatch(rec["runs"].get(n), dict(learning))]
    if stale:
        what = sorted({k for n in stale for k in mismatch(rec["runs"][n], dict(learning))})
        raise PlanConflict(f"holds learning runs made by other learner code ({_names(stale)}; changed: "
                           f"{', '.join(what)}): remove their runs/<run>.db* to run them again with "
                           "this code (the trials in trials.db are kept and reused), or use another --out")
    record = {
        "experiments": {**rec["experiments"], **{e: {f: values[f] for f in FIELDS[e]} for e in experiments}},
        "model": dict(model),
        "runs": {**rec["runs"], **{n: dict(learning) for n in runs if n not in existing}},
    }
    return Resolved(sizes, quick, record)
