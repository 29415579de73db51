"""Reading a simulator prior (``ersac-hil daemon --prior PATH``) from what the simulator made.

PATH is one of:

- a landscape: a JSON file with ``rows`` of ``theta``, ``mean``, ``std`` (``bench/bracing_sweep.py
  --out``'s ``landscape.json``), or a ``reproduce`` ``results.json`` (its bracing landscape);
- a ``reproduce`` output directory: its ``results.json`` landscape if there is one for the
  task, else its ``trials.db``: the independent episodes of the task grouped by policy
  (groups of at least ``MIN_GROUP`` episodes), costed under the run's weights;
- a daemon store (``.db``): the last run of the task in it, its offline selection for kappa
  (the learner rebuilt exactly as the run left it).

The result is a :class:`~ersac_hil.learner.prior.SimPrior` for the run's kappa, with the
simulated damage rate at its optimum where PATH has one (a landscape's ``damage`` column, the
``damage`` term of the trials); stores are read as they are (read-only).
"""
from __future__ import annotations

import json
import sqlite3
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ersac_hil.learner.prior import SimPrior, from_groups
from protocol.zenoh import damaged, get_task

__all__ = ["PriorError", "load_prior", "MIN_GROUP"]

MIN_GROUP = 5


class PriorError(ValueError):
    """A prior PATH that cannot be used (the message says why)."""


def load_prior(path: str | Path, task: str, kappa: float, weights: Mapping[str, float]) -> SimPrior:
    p = Path(path)
    if not p.exists():
        raise PriorError(f"--prior {p}: no such file or directory")
    try:
        if p.is_dir():
            results = p / "results.json"
            if results.exists() and task == "bracing" and _rows(json.loads(results.read_text())) is not None:
                return _from_json(results, task, kappa)
            if (p / "trials.db").exists():
                return _from_trials(p / "trials.db", task, kappa, weights)
            raise PriorError(f"--prior {p}: neither a results.json landscape nor a trials.db in it")
        if p.suffix == ".json":
            return _from_json(p, task, kappa)
        return _from_store(p, task, kappa, weights)
    except PriorError:
        raise
    except (OSError, ValueError, KeyError, TypeError, sqlite3.Error) as exc:
        raise PriorError(f"--prior {p}: {type(exc).__name__}: {exc}") from None


def _rows(doc: object) -> list | None:
    if isinstance(doc, Mapping):
        if isinstance(doc.get("rows"), list):
            return doc["rows"]
        for key in ("bracing", "landscape"):
            if key in doc:
                found = _rows(doc[key])
                if found is not None:
                    return found
    return None


def _from_json(path: Path, task: str, kappa: float) -> SimPrior:
    rows = _rows(json.loads(path.read_text()))
    if not rows:
        raise PriorError(f"--prior {path}: no landscape rows (theta, mean, std) in it")
    if task != "bracing":
        raise PriorError(f"--prior {path}: a landscape of the bracing task, not of {task}")
    thetas = [[float(r["theta"])] for r in rows]
    damages = [float(r["damage"]) for r in rows] if all("damage" in r for r in rows) else None
    return from_groups(thetas, [float(r["mean"]) for r in rows], [float(r["std"]) for r in rows], kappa,
                       f"landscape {path.name} ({len(rows)} policies)", damages)


def _from_trials(path: Path, task: str, kappa: float, weights: Mapping[str, float]) -> SimPrior:
    spec = get_task(task)
    groups: dict[tuple[float, ...], list[float]] = defaultdict(list)
    broke: dict[tuple[float, ...], list[bool]] = defaultdict(list)
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
        for theta, terms in db.execute("SELECT theta, cost_terms FROM trials WHERE task = ? AND status = 'ok'", (task,)):
            t, terms = tuple(json.loads(theta)), json.loads(terms)
            groups[t].append(spec.total_cost(terms, weights))
            broke[t].append(bool(damaged(terms)))
    keep = [(t, np.asarray(c)) for t, c in groups.items() if len(c) >= MIN_GROUP]
    if not keep:
        raise PriorError(f"--prior {path}: no policy of {task} with at least {MIN_GROUP} episodes")
    damages = [float(np.mean(broke[t])) for t, _ in keep] if "damage" in spec.term_names else None
    return from_groups([t for t, _ in keep], [float(c.mean()) for _, c in keep],
                       [float(c.std(ddof=1)) for _, c in keep], kappa,
                       f"trials {path.parent.name}/{path.name} ({len(keep)} policies)", damages)


def _from_store(path: Path, task: str, kappa: float, weights: Mapping[str, float]) -> SimPrior:
    from .engine import NotEnoughData
    from .runs import rebuild_engine
    from .store import Store, StoreError
    try:
        with Store(path, readonly=True) as store:
            runs = [r for r in store.runs() if r.task == task]
            if not runs:
                raise PriorError(f"--prior {path}: no {task} run in this store")
            engine = rebuild_engine(store, runs[-1])
    except StoreError as exc:
        raise PriorError(f"--prior {path}: {exc}") from None
    engine.set_weights(dict(weights))
    try:
        theta, J, r = engine.select(kappa)
    except NotEnoughData as exc:
        raise PriorError(f"--prior {path}: {exc}") from None
    return SimPrior(tuple(theta), J, r, float(kappa), f"store {path.name} run {runs[-1].run_id}")
