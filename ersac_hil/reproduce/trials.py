"""Independent episodes (test trials, random policies, Monte Carlo landscapes) and their store.

A trial is one ``episode/run`` request with a fixed theta and scenario seed, sent straight to
an agent (``ersac_hil.daemon.agents.AgentLink``): no learner is involved. The simulator is
deterministic, so a trial is identified by its content, ``(task, theta, seed)``: the same
request is never run twice, whichever experiment asks for it (the lifting "after 30 episodes"
test trials are the contexts' "prior" column).

:class:`TrialStore` is SQLite (WAL), one row per finished trial, committed as soon as it
arrives, so an interrupted ``ersac-hil reproduce`` resumes where it stopped. Faults (the agent's
fault statuses, timeouts, a lost agent) are retried with a backoff; a refusal is stored (the
agent will refuse it again).
"""
from __future__ import annotations

import json
import sqlite3
import threading
import time
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol.zenoh import EpisodeRequest, EpisodeResult, get_task
from protocol.zenoh.tasks import LIFTING_GOAL_HEIGHT_M, LIFTING_GOAL_TOLERANCE_M

__all__ = ["TrialSpec", "Trial", "TrialStore", "TrialFailed", "run_trial", "lifted"]

#: Attempts of one trial before giving up (faults under load are retried).
MAX_ATTEMPTS = 10

_SCHEMA = """
CREATE TABLE IF NOT EXISTS trials (
    key        TEXT PRIMARY KEY,
    task       TEXT NOT NULL,
    theta      TEXT NOT NULL,
    seed       INTEGER NOT NULL,
    status     TEXT NOT NULL,
    cost_terms TEXT,
    failures   TEXT,
    telemetry  TEXT,
    detail     TEXT NOT NULL DEFAULT '',
    wall_s     REAL,
    stamp_s    REAL NOT NULL
);
"""


class TrialFailed(RuntimeError):
    """A trial kept failing (``MAX_ATTEMPTS`` faults in a row)."""


@dataclass(frozen=True)
class TrialSpec:
    """One independent episode: ``task``, ``theta`` (dim,) inside the task box, scenario ``seed``."""

    task: str
    theta: tuple[float, ...]
    seed: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "theta", tuple(float(t) for t in get_task(self.task).check_theta(self.theta)))

    @property
    def key(self) -> str:
        return f"{self.task}:{json.dumps(list(self.theta))}:{self.seed}"


@dataclass(frozen=True)
class Trial:
    """A finished trial: ``status`` ``ok`` or the refusal ``refused``; terms, failure flags and
    the telemetry summary of an ``ok`` one."""

    spec: TrialSpec
    status: str
    cost_terms: Mapping[str, float]
    failures: Mapping[str, bool]
    telemetry: Mapping[str, float]
    detail: str
    wall_s: float | None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def failed(self, flag: str) -> bool:
        return bool(self.failures.get(flag, False))

    def cost(self, weights: Mapping[str, float] | None = None) -> float:
        """The total cost under ``weights`` (default: the task's)."""
        return get_task(self.spec.task).total_cost(self.cost_terms, weights)

    def lifted(self) -> bool:
        """An ``ok`` lifting trial that succeeded (:func:`lifted`)."""
        return self.ok and lifted(self.telemetry, self.failures)


def lifted(telemetry: Mapping[str, float], failures: Mapping[str, bool]) -> bool:
    """A lifting episode's success (the paper's Fig. 4: "bottle above the shoulder, goal height
    reached"): the bottle neither dropped nor the robot fallen, and the bottle's final height
    within the contract's tolerance of the goal height."""
    h = telemetry.get("final_bottle_height_m", float("nan"))
    return (not failures.get("bottle_dropped", False) and not failures.get("fallen", False)
            and abs(h - LIFTING_GOAL_HEIGHT_M) <= LIFTING_GOAL_TOLERANCE_M)


class TrialStore:
    """The trials of one ``reproduce`` output directory (thread-safe: one connection, a lock)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(_SCHEMA)
        self._lock = threading.Lock()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> TrialStore:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def put(self, spec: TrialSpec, result: EpisodeResult | None, status: str, detail: str = "") -> None:
        """Commit one finished trial (``result`` None for a refusal)."""
        row = (spec.key, spec.task, json.dumps(list(spec.theta)), spec.seed, status,
               json.dumps(dict(result.cost_terms)) if result else None,
               json.dumps(dict(result.failures)) if result else None,
               json.dumps(dict(result.telemetry)) if result else None,
               detail[:2000], result.wall_s if result else None, time.time())
        with self._lock:
            self._db.execute("INSERT OR REPLACE INTO trials VALUES (?,?,?,?,?,?,?,?,?,?,?)", row)

    def get(self, specs: Iterable[TrialSpec]) -> dict[TrialSpec, Trial]:
        """The stored trials among ``specs``."""
        specs = list(specs)
        out: dict[TrialSpec, Trial] = {}
        with self._lock:
            for spec in specs:
                row = self._db.execute("SELECT status, cost_terms, failures, telemetry, detail, wall_s "
                                       "FROM trials WHERE key = ?", (spec.key,)).fetchone()
                if row is not None:
                    out[spec] = Trial(spec, row[0], _loads(row[1]), _loads(row[2]), _loads(row[3]),
                                      row[4], row[5])
        return out

    def missing(self, specs: Iterable[TrialSpec]) -> list[TrialSpec]:
        """``specs`` not stored yet, in order, without duplicates."""
        seen: set[str] = set()
        out = []
        with self._lock:
            for spec in specs:
                if spec.key in seen:
                    continue
                seen.add(spec.key)
                if self._db.execute("SELECT 1 FROM trials WHERE key = ?", (spec.key,)).fetchone() is None:
                    out.append(spec)
        return out

    def count(self, keys: Iterable[str] | None = None) -> int:
        with self._lock:
            if keys is None:
                return int(self._db.execute("SELECT COUNT(*) FROM trials").fetchone()[0])
            return sum(self._db.execute("SELECT 1 FROM trials WHERE key = ?", (k,)).fetchone() is not None
                       for k in set(keys))


def _loads(text: str | None) -> dict[str, Any]:
    return json.loads(text) if text else {}


def run_trial(link: Any, store: TrialStore, spec: TrialSpec, stop: threading.Event,
              backoff_s: Sequence[float] = (0.5, 10.0)) -> None:
    """Run ``spec`` on the agent behind ``link`` (an ``AgentLink``) and store it; retries
    faults. Raises ``TrialFailed`` after ``MAX_ATTEMPTS`` faults, returns early when ``stop``."""
    wait = backoff_s[0]
    last = ""
    for attempt in range(MAX_ATTEMPTS):
        if stop.is_set():
            return
        link.wait_ready(None)
        eid = f"trial-{zlib.crc32(spec.key.encode()):08x}-{time.time_ns() % 10**12}-{attempt}"
        outcome = link.run(EpisodeRequest(eid, spec.task, spec.theta, spec.seed))
        if outcome.status == "ok":
            store.put(spec, outcome.result, "ok")
            return
        if outcome.status == "interrupted":
            return
        if outcome.status == "refused" and outcome.code in ("invalid_request", "unknown_task"):
            store.put(spec, None, "refused", f"{outcome.code}: {outcome.detail}")
            return
        last = f"{outcome.status}: {outcome.detail}"
        if stop.wait(wait):
            return
        wait = min(2 * wait, backoff_s[1])
    raise TrialFailed(f"trial {spec.key}: {MAX_ATTEMPTS} failed attempts, last {last}")
