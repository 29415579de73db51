"""The daemon's embedded store: SQLite in WAL mode, one file per deployment.

Tables (schema version :data:`SCHEMA_VERSION`, in ``PRAGMA user_version``)::

    runs      one learning run: robot, task, seed, learner settings (JSON), status
    episodes  one row per *attempt*: the request (base theta, perturbation z, executed theta,
              scenario seed), the outcome (status, cost terms, cost under the current
              weights, failure flags, telemetry summary, fault counters, the file name of the
              agent's CAN trace of the episode, if it recorded one, and of its MCAP file) and
              timestamps.
              ``idx`` is the learner episode the attempt serves; at most one "ok" attempt
              per (run, idx) (a partial unique index enforces it). ``update_idx``: the
              update an ok episode fed (NULL while its batch is incomplete).
    updates   one row per learner update: with ``batch`` k = 1 (the paper's Algorithm 1) one
              per ok episode, same idx; with k > 1 one per k ok episodes (``idx`` counts
              updates, ``episode_id`` is the batch's last episode): theta before/after,
              the cost told, J~(theta), r~(theta), r~(theta+z), the TD error (all NULL
              during the learner's warm-up), kappa, step size and the learner's resumable
              state after the update (``ERSAC.get_state()``: RNG, theta, critic fit; JSON).
    changes   kappa / weights / theta (adopted selection) changes with their source and the
              number of updates done when they took effect.

Write rules: an attempt is inserted as ``pending`` (committed) before its query is sent; a
successful episode and its update are committed in ONE transaction before the next episode
starts; a failed attempt is committed with its status and is never told to the learner.
A weights change and the re-costing of every stored ok episode are one transaction.

A store of an older schema is migrated in place when opened for writing (schema 1 -> 2: the
``trace`` column; 2 -> 3: ``episodes.update_idx``, filled from the updates of the time, one
episode each; 3 -> 4: ``episodes.mcap``, empty for the episodes of the time); where the stored ``episodes``
table is not today's definition (a CHECK of the attempt statuses of its time), it is rebuilt
once with today's, every row kept. Read-only opens read it as it is.

One connection shared by the daemon's threads, serialised by a lock. JSON columns hold
floats as ``repr`` text, so values round-trip exactly.
"""
from __future__ import annotations

import errno
import json
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

from protocol.zenoh import STATUSES, EpisodeResult, get_task

__all__ = [
    "SCHEMA_VERSION",
    "RUN_STATUSES",
    "ATTEMPT_STATUSES",
    "DAEMON_STATUSES",
    "CHANGE_KINDS",
    "StoreError",
    "RunNotFound",
    "StoreUnwritable",
    "Store",
    "RunRecord",
    "EpisodeRecord",
    "UpdateRecord",
    "ChangeRecord",
]

SCHEMA_VERSION = 4
#: Older schemas this code opens (read-write ones are migrated in place): 1 lacks
#: ``episodes.trace``, 2 lacks ``episodes.update_idx`` (every update then had one episode),
#: 3 lacks ``episodes.mcap``.
_MIGRATIONS = {
    1: "ALTER TABLE episodes ADD COLUMN trace TEXT NOT NULL DEFAULT ''",
    2: "ALTER TABLE episodes ADD COLUMN update_idx INTEGER; "
       "UPDATE episodes SET update_idx = (SELECT u.idx FROM updates u WHERE u.episode_id = episodes.episode_id)",
    3: "ALTER TABLE episodes ADD COLUMN mcap TEXT NOT NULL DEFAULT ''",
}
RUN_STATUSES: tuple[str, ...] = ("running", "finished", "failed")
#: Agent statuses (``protocol.zenoh.STATUSES``) plus the daemon's own: pending (sent, no
#: answer yet), timeout (no reply in time), lost (the agent's liveliness token vanished while
#: the episode ran), refused (agent reply_err), bad_reply (a reply that breaks the contract),
#: interrupted (the daemon stopped or died while the attempt was pending).
DAEMON_STATUSES: tuple[str, ...] = ("pending", "timeout", "lost", "refused", "bad_reply", "interrupted")
ATTEMPT_STATUSES: tuple[str, ...] = (*STATUSES, *DAEMON_STATUSES)
CHANGE_KINDS: tuple[str, ...] = ("kappa", "weights", "theta")

_SCHEMA = f"""
CREATE TABLE runs (
    run_id      TEXT PRIMARY KEY,
    robot       TEXT NOT NULL,
    task        TEXT NOT NULL,
    seed        INTEGER NOT NULL,
    settings    TEXT NOT NULL,
    status      TEXT NOT NULL CHECK (status IN {RUN_STATUSES!r}),
    detail      TEXT NOT NULL DEFAULT '',
    created_s   REAL NOT NULL,
    updated_s   REAL NOT NULL
);
CREATE TABLE episodes (
    seq         INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id      TEXT NOT NULL REFERENCES runs(run_id),
    episode_id  TEXT NOT NULL UNIQUE,
    idx         INTEGER NOT NULL CHECK (idx >= 0),
    attempt     INTEGER NOT NULL CHECK (attempt >= 0),
    base_theta  TEXT NOT NULL,
    z           TEXT NOT NULL,
    theta       TEXT NOT NULL,
    seed        INTEGER NOT NULL,
    status      TEXT NOT NULL CHECK (status IN {ATTEMPT_STATUSES!r}),
    cost_terms  TEXT,
    cost        REAL,
    agent_cost  REAL,
    failures    TEXT,
    telemetry   TEXT,
    fault_counts TEXT,
    duration_s  REAL,
    wall_s      REAL,
    detail      TEXT NOT NULL DEFAULT '',
    requested_s REAL NOT NULL,
    finished_s  REAL,
    trace       TEXT NOT NULL DEFAULT '',
    update_idx  INTEGER,
    mcap        TEXT NOT NULL DEFAULT '',
    UNIQUE (run_id, idx, attempt)
);
CREATE UNIQUE INDEX episodes_one_ok ON episodes(run_id, idx) WHERE status = 'ok';
CREATE TABLE updates (
    run_id      TEXT NOT NULL REFERENCES runs(run_id),
    idx         INTEGER NOT NULL,
    episode_id  TEXT NOT NULL UNIQUE REFERENCES episodes(episode_id),
    theta_before TEXT NOT NULL,
    theta_after TEXT NOT NULL,
    cost        REAL NOT NULL,
    J           REAL,
    r           REAL,
    r_z         REAL,
    td_error    REAL,
    kappa       REAL NOT NULL,
    lr          REAL NOT NULL,
    state       TEXT NOT NULL,
    stamp_s     REAL NOT NULL,
    PRIMARY KEY (run_id, idx)
);
CREATE TABLE changes (
    seq         INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id      TEXT NOT NULL REFERENCES runs(run_id),
    kind        TEXT NOT NULL CHECK (kind IN {CHANGE_KINDS!r}),
    value       TEXT NOT NULL,
    source      TEXT NOT NULL,
    n_updates   INTEGER NOT NULL,
    stamp_s     REAL NOT NULL
);
CREATE INDEX episodes_run ON episodes(run_id, idx, attempt);
CREATE INDEX changes_run ON changes(run_id, kind, seq);
PRAGMA user_version = {SCHEMA_VERSION};
"""


def _episodes_sql() -> str:
    """The ``CREATE TABLE episodes`` statement of today's schema (what ``sqlite_master`` keeps)."""
    start = _SCHEMA.index("CREATE TABLE episodes")
    return _SCHEMA[start:_SCHEMA.index(";", start)]


def _episodes_indexes() -> str:
    return "".join(line + "\n" for line in _SCHEMA.splitlines()
                   if line.startswith("CREATE") and " ON episodes(" in line)


def _definition(create_table: str) -> str:
    """A CREATE TABLE statement's column list, whitespace-normalised (a renamed table's stored
    statement quotes its name)."""
    return " ".join(create_table[create_table.index("("):].split())


def _refresh_episodes_table(db: sqlite3.Connection) -> None:
    """Rebuild ``episodes`` where its stored definition is not today's.

    SQLite cannot change a CHECK constraint in place, and ``ALTER TABLE ... ADD COLUMN`` keeps the
    old one: a store created before an attempt status existed (``stopped`` of the e-stop, say)
    would refuse that status. So the table is rebuilt once with today's definition (every row
    and ``seq`` kept, its indexes re-created), in one transaction, following SQLite's own
    procedure for schema changes (foreign keys off while the table is swapped, checked before
    the commit). A store whose table is already today's is left untouched.
    """
    stored = db.execute("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'episodes'").fetchone()
    wanted = _episodes_sql()
    if stored is None or _definition(stored[0]) == _definition(wanted):
        return
    columns = [row[1] for row in db.execute("PRAGMA table_info(episodes)")]
    listed = ", ".join(columns)
    db.execute("PRAGMA foreign_keys = OFF")
    try:
        db.executescript(
            "BEGIN; " + wanted.replace("CREATE TABLE episodes", "CREATE TABLE episodes_rebuilt", 1) + "; "
            f"INSERT INTO episodes_rebuilt ({listed}) SELECT {listed} FROM episodes; "
            "DROP TABLE episodes; ALTER TABLE episodes_rebuilt RENAME TO episodes; "
            + _episodes_indexes())
        broken = db.execute("PRAGMA foreign_key_check").fetchall()
        if broken:
            db.execute("ROLLBACK")
            raise StoreError(f"rebuilding the episodes table would break {len(broken)} references")
        db.execute("COMMIT")
    except sqlite3.DatabaseError:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
    finally:
        db.execute("PRAGMA foreign_keys = ON")


class StoreError(RuntimeError):
    """The store cannot do what was asked (wrong schema, inconsistent write...)."""


class RunNotFound(StoreError):
    """No run with that id."""


class StoreUnwritable(StoreError):
    """SQLite could not write a transaction (the disk is full, an I/O error, the file is read-only
    or locked by another writer): nothing of the transaction is stored, what was committed before
    stays as it was; the run is resumable once the cause is gone."""


_UNWRITABLE = ("SQLITE_FULL", "SQLITE_IOERR", "SQLITE_READONLY", "SQLITE_BUSY", "SQLITE_LOCKED", "SQLITE_CANTOPEN")
"""SQLite's result codes (and their extended codes) of a write the file system or another writer refused."""


def _wal(path: Path) -> Path:
    return path.with_name(path.name + "-wal")


_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO)
"""The errors of a file system that has no room (or cannot write), not of a wrong path."""


def _remove_new(path: Path, made: Sequence[Path]) -> None:
    """Remove a store that was being created at ``path`` (its file, journals) and the
    directories ``made`` for it (deepest first), as far as they are there and empty."""
    for name in (path.name, path.name + "-wal", path.name + "-shm", path.name + "-journal"):
        path.with_name(name).unlink(missing_ok=True)
    for directory in made:
        try:
            directory.rmdir()
        except OSError:
            break


def _dumps(value: Any) -> str:
    return json.dumps(value, allow_nan=False, separators=(",", ":"))


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _opt(value: float | None) -> float | None:
    return None if value is None else float(value)


def _vec(values: Sequence[float]) -> str:
    return _dumps([float(v) for v in values])


@dataclass(frozen=True)
class RunRecord:
    """One learning run. ``settings``: the learner fields of ``DaemonConfig`` (JSON)."""

    run_id: str
    robot: str
    task: str
    seed: int
    settings: Mapping[str, Any]
    status: str
    detail: str
    created_s: float
    updated_s: float


@dataclass(frozen=True)
class EpisodeRecord:
    """One attempt. Vectors are tuples of shape ``(dim,)``; outcome fields are ``None``
    while pending. ``cost`` is the cost of an ok episode under the run's current weights."""

    seq: int
    run_id: str
    episode_id: str
    idx: int
    attempt: int
    base_theta: tuple[float, ...]
    z: tuple[float, ...]
    theta: tuple[float, ...]
    seed: int
    status: str
    cost_terms: Mapping[str, float] | None
    cost: float | None
    agent_cost: float | None
    failures: Mapping[str, bool] | None
    telemetry: Mapping[str, float] | None
    fault_counts: Mapping[str, int] | None
    duration_s: float | None
    wall_s: float | None
    detail: str
    requested_s: float
    finished_s: float | None
    trace: str = ""
    update_idx: int | None = None
    mcap: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


@dataclass(frozen=True)
class UpdateRecord:
    """One learner update, the daemon's only update record: the engine builds it from the
    learner's ``Update``, the store keeps and returns it. ``idx``: the update's index (the
    ok episode's idx when every update has one episode); ``episodes``: the ids of the ok
    episodes that fed it, in idx order (``episode_id`` is the last); for a batch of k > 1
    ``cost``, ``r_z`` and ``td_error`` are means over its episodes. ``J``
    (= J~(theta_before)), ``r`` (= r~(theta_before)), ``r_z`` (= r~ at the executed theta)
    and ``td_error`` are ``None`` for warm-up updates (no step); ``lr`` is the step size
    eta / r~ after clipping; ``state``: the learner's resumable state after the update."""

    run_id: str
    idx: int
    episode_id: str
    theta_before: tuple[float, ...]
    theta_after: tuple[float, ...]
    cost: float
    J: float | None
    r: float | None
    r_z: float | None
    td_error: float | None
    kappa: float
    lr: float
    state: Mapping[str, Any]
    stamp_s: float
    episodes: tuple[str, ...] = ()

    @property
    def warmup(self) -> bool:
        """A warm-up tell: the learner stored the episode but took no step."""
        return self.J is None


@dataclass(frozen=True)
class ChangeRecord:
    """A kappa / weights / theta change; ``n_updates``: updates done when it took effect."""

    seq: int
    run_id: str
    kind: str
    value: Any
    source: str
    n_updates: int
    stamp_s: float


def _tuple(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in json.loads(text))


def _run(row: sqlite3.Row) -> RunRecord:
    return RunRecord(row["run_id"], row["robot"], row["task"], int(row["seed"]),
                     json.loads(row["settings"]), row["status"], row["detail"],
                     row["created_s"], row["updated_s"])


def _episode(row: sqlite3.Row) -> EpisodeRecord:
    return EpisodeRecord(
        row["seq"], row["run_id"], row["episode_id"], row["idx"], row["attempt"],
        _tuple(row["base_theta"]), _tuple(row["z"]), _tuple(row["theta"]), int(row["seed"]),
        row["status"], _loads(row["cost_terms"]), row["cost"], row["agent_cost"],
        _loads(row["failures"]), _loads(row["telemetry"]), _loads(row["fault_counts"]),
        row["duration_s"], row["wall_s"], row["detail"], row["requested_s"], row["finished_s"],
        row["trace"] if "trace" in row.keys() else "",
        row["update_idx"] if "update_idx" in row.keys() else None,
        row["mcap"] if "mcap" in row.keys() else "",
    )


def _update(row: sqlite3.Row, fed: Sequence[str]) -> UpdateRecord:
    return UpdateRecord(
        run_id=row["run_id"], idx=row["idx"], episode_id=row["episode_id"],
        theta_before=_tuple(row["theta_before"]), theta_after=_tuple(row["theta_after"]),
        cost=row["cost"], J=row["J"], r=row["r"], r_z=row["r_z"], td_error=row["td_error"],
        kappa=row["kappa"], lr=row["lr"], state=json.loads(row["state"]), stamp_s=row["stamp_s"],
        episodes=tuple(fed) or (row["episode_id"],),
    )


def _change(row: sqlite3.Row) -> ChangeRecord:
    return ChangeRecord(row["seq"], row["run_id"], row["kind"], json.loads(row["value"]),
                        row["source"], row["n_updates"], row["stamp_s"])


class Store:
    """The SQLite store. Thread-safe (one connection, one lock). Use as a context manager.

    Args:
        path: database file (created with its directory if missing).
        readonly: open an existing store for reading (reports); never creates or migrates,
            and leaves no ``-wal``/``-shm`` files behind that were not there before.

    Raises:
        StoreError: the file is not an ersac-hil store (an empty file, another program's
            SQLite file, not SQLite at all) or of a schema this code cannot open; the file
            is left as it was.
    """

    def __init__(self, path: str | Path, *, readonly: bool = False) -> None:
        self.path = Path(path)
        self._lock = threading.RLock()
        existed = self.path.exists()
        if readonly:
            if not self.path.is_file():
                raise StoreError(f"no store at {self.path}")
            # without a WAL file beside it nobody has the store open and nothing waits to be
            # checkpointed: read the file as it is, so that reading creates no -wal/-shm files
            quiet = "&immutable=1" if not _wal(self.path).exists() else ""
            uri = f"file:{quote(str(self.path.resolve()))}?mode=ro{quiet}"
            self._db = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
        else:
            if existed and not self.path.is_file():
                raise StoreError(f"{self.path} is not a file")
            made = [d for d in (self.path.parent, *self.path.parent.parents) if not d.exists()]
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                _remove_new(self.path, made)
                error = StoreUnwritable if exc.errno in _NO_SPACE else StoreError
                raise error(f"store {self.path} cannot be created: {exc.strerror}") from exc
            self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False,
                                       timeout=10.0)
        self._db.row_factory = sqlite3.Row
        try:
            self._db.execute("PRAGMA busy_timeout = 10000")
            # what the file is, read before anything is written to it
            version = self._db.execute("PRAGMA user_version").fetchone()[0]
            tables = self._db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
            if version == 0 and existed:
                what = "an empty file" if self.path.stat().st_size == 0 else "an SQLite file of another program"
                raise StoreError(f"{self.path} is not an ersac-hil store ({what})")
            if version != SCHEMA_VERSION and version not in _MIGRATIONS and existed:
                raise StoreError(f"{self.path}: store schema {version}, this code needs {SCHEMA_VERSION}")
            if not readonly:
                mode = self._db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
                if mode.lower() != "wal":
                    raise StoreError(f"{self.path}: cannot switch to WAL (journal_mode={mode})")
                self._db.execute("PRAGMA synchronous = FULL")
            self._db.execute("PRAGMA foreign_keys = ON")
            if version == 0 and not tables:  # a new file
                self._db.executescript(_SCHEMA)
            elif version in _MIGRATIONS and not readonly:
                while version in _MIGRATIONS:  # each step in its own transaction
                    self._db.executescript(f"BEGIN; {_MIGRATIONS[version]}; "
                                           f"PRAGMA user_version = {version + 1}; COMMIT;")
                    version += 1
            if not readonly:
                _refresh_episodes_table(self._db)
        except sqlite3.DatabaseError as exc:
            self._db.close()
            if existed:
                raise StoreError(f"{self.path}: not an ersac-hil store ({exc})") from exc
            _remove_new(self.path, made)  # nothing half-written: no file, no directory of it
            if getattr(exc, "sqlite_errorname", "").startswith(("SQLITE_FULL", "SQLITE_IOERR")):
                raise StoreUnwritable(f"store {self.path} cannot be created: {exc}; is the disk full?") from exc
            raise StoreError(f"{self.path}: {exc}") from exc
        except StoreError:
            self._db.close()
            raise

    # ------------------------------------------------------------------ plumbing
    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` (``ROLLBACK`` on error), under the lock.

        Raises:
            StoreUnwritable: SQLite could not write it (``SQLITE_FULL``, ``SQLITE_IOERR``...,
                also a failed ``COMMIT``): rolled back, nothing of it stored.
        """
        with self._lock:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    yield self._db
                    self._db.execute("COMMIT")
                except BaseException:
                    if self._db.in_transaction:  # SQLite rolls back by itself after some I/O errors
                        try:
                            self._db.execute("ROLLBACK")
                        except sqlite3.Error:
                            pass  # the transaction is gone: its journal frames were never committed
                    raise
            except sqlite3.OperationalError as exc:
                name = getattr(exc, "sqlite_errorname", "")
                if not name.startswith(_UNWRITABLE):
                    raise  # a mistake of this code (no such table...), not of the disk
                hint = "; is the disk full?" if name.startswith(("SQLITE_FULL", "SQLITE_IOERR")) else ""
                raise StoreUnwritable(f"store {self.path} cannot be written: {exc}{hint}") from exc

    def _query(self, sql: str, params: Sequence[Any] = ()) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute(sql, params).fetchall()

    def _rows_of_run(self, table: str, run_id: str, column: str, value: str | None) -> list[sqlite3.Row]:
        """The rows of ``table`` (a table of this schema) of one run in insertion order; with a
        ``value``, only those whose ``column`` holds it."""
        if value is None:
            return self._query(f"SELECT * FROM {table} WHERE run_id = ? ORDER BY seq", (run_id,))
        return self._query(f"SELECT * FROM {table} WHERE run_id = ? AND {column} = ? ORDER BY seq",
                           (run_id, value))

    @property
    def journal_mode(self) -> str:
        return str(self._query("PRAGMA journal_mode")[0][0])

    # ------------------------------------------------------------------ runs
    def create_run(self, run_id: str, robot: str, task: str, seed: int,
                   settings: Mapping[str, Any], stamp_s: float | None = None) -> RunRecord:
        """Insert a new ``running`` run. Raises :class:`StoreError` if the id exists."""
        now = time.time() if stamp_s is None else stamp_s
        try:
            with self.transaction() as db:
                db.execute(
                    "INSERT INTO runs VALUES (?, ?, ?, ?, ?, 'running', '', ?, ?)",
                    (run_id, robot, task, int(seed), _dumps(dict(settings)), now, now),
                )
        except sqlite3.IntegrityError as exc:
            raise StoreError(f"run {run_id!r} already exists") from exc
        return self.run(run_id)

    def run(self, run_id: str) -> RunRecord:
        rows = self._query("SELECT * FROM runs WHERE run_id = ?", (run_id,))
        if not rows:
            raise RunNotFound(f"no run {run_id!r} in {self.path}")
        return _run(rows[0])

    def runs(self) -> list[RunRecord]:
        return [_run(r) for r in self._query("SELECT * FROM runs ORDER BY created_s, rowid")]

    def latest_run(self, robot: str, task: str) -> RunRecord | None:
        """The most recently created run of ``robot``/``task``, whatever its status."""
        rows = self._query("SELECT * FROM runs WHERE robot = ? AND task = ? "
                           "ORDER BY created_s DESC, rowid DESC LIMIT 1", (robot, task))
        return _run(rows[0]) if rows else None

    def latest_unfinished(self, robot: str, task: str) -> RunRecord | None:
        """The most recently created run of ``robot``/``task`` that is still ``running``."""
        rows = self._query(
            "SELECT * FROM runs WHERE robot = ? AND task = ? AND status = 'running' "
            "ORDER BY created_s DESC, rowid DESC LIMIT 1", (robot, task))
        return _run(rows[0]) if rows else None

    def set_run_status(self, run_id: str, status: str, detail: str = "",
                       settings: Mapping[str, Any] | None = None) -> None:
        if status not in RUN_STATUSES:
            raise StoreError(f"run status {status!r} not in {RUN_STATUSES}")
        with self.transaction() as db:
            cur = db.execute("UPDATE runs SET status = ?, detail = ?, updated_s = ? WHERE run_id = ?",
                             (status, detail, time.time(), run_id))
            if settings is not None:
                db.execute("UPDATE runs SET settings = ? WHERE run_id = ?", (_dumps(dict(settings)), run_id))
            if cur.rowcount != 1:
                raise RunNotFound(f"no run {run_id!r}")

    # ------------------------------------------------------------------ episodes
    def begin_attempt(self, run_id: str, episode_id: str, idx: int, attempt: int,
                      base_theta: Sequence[float], z: Sequence[float], theta: Sequence[float],
                      seed: int, stamp_s: float | None = None) -> None:
        """Commit a ``pending`` attempt before its request is sent."""
        now = time.time() if stamp_s is None else stamp_s
        try:
            with self.transaction() as db:
                db.execute(
                    "INSERT INTO episodes (run_id, episode_id, idx, attempt, base_theta, z, theta, seed,"
                    " status, requested_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?, 'pending', ?)",
                    (run_id, episode_id, idx, attempt, _vec(base_theta), _vec(z), _vec(theta),
                     int(seed), now),
                )
        except sqlite3.IntegrityError as exc:
            raise StoreError(f"attempt {episode_id!r} (idx {idx}, attempt {attempt}): {exc}") from exc

    def _finish(self, db: sqlite3.Connection, episode_id: str, status: str,
                result: EpisodeResult | None, cost: float | None, detail: str) -> None:
        if status not in ATTEMPT_STATUSES or status == "pending":
            raise StoreError(f"cannot finish an attempt with status {status!r}")
        values: dict[str, Any] = {"status": status, "cost": cost, "detail": detail,
                                  "finished_s": time.time()}
        if result is not None:
            values.update(
                cost_terms=_dumps(dict(result.cost_terms)), agent_cost=result.total_cost,
                failures=_dumps(dict(result.failures)), telemetry=_dumps(dict(result.telemetry)),
                fault_counts=_dumps(dict(result.fault_counts)), duration_s=result.duration_s,
                wall_s=result.wall_s, detail=detail or result.detail, trace=result.trace,
                mcap=result.mcap,
            )
        sets = ", ".join(f"{k} = ?" for k in values)
        cur = db.execute(f"UPDATE episodes SET {sets} WHERE episode_id = ? AND status = 'pending'",
                         (*values.values(), episode_id))
        if cur.rowcount != 1:
            raise StoreError(f"attempt {episode_id!r} is not pending")

    def record_failure(self, episode_id: str, status: str, detail: str,
                       result: EpisodeResult | None = None) -> None:
        """Commit a failed attempt (fault status, timeout, refusal): not told to the learner."""
        if status == "ok":
            raise StoreError("an ok episode is recorded with record_success")
        with self.transaction() as db:
            self._finish(db, episode_id, status, result, None, detail)

    def record_ok(self, episode_id: str, result: EpisodeResult, cost: float) -> None:
        """Commit an ok episode whose update waits for the rest of its batch."""
        if not result.ok:
            raise StoreError("record_ok needs an ok result")
        with self.transaction() as db:
            self._finish(db, episode_id, "ok", result, float(cost), "")

    def record_success(self, episode_id: str | None, result: EpisodeResult | None, cost: float | None,
                       update: UpdateRecord) -> None:
        """Commit an ok episode AND the learner update it completes, in one transaction.

        ``update.episodes`` (default: ``episode_id`` alone) are the episodes that fed the
        update, in idx order; ``update.episode_id`` is the last of them. Those other than
        ``episode_id`` (a batch) must be committed ok already (:meth:`record_ok`).
        ``episode_id`` None: every episode of the update is committed already (a resumed
        daemon whose batch shrank with a smaller budget).
        """
        fed = update.episodes or (episode_id,)
        if (episode_id is not None and (result is None or not result.ok or episode_id not in fed)) \
                or update.episode_id != fed[-1]:
            raise StoreError("record_success needs an ok result and its own update")
        with self.transaction() as db:
            if episode_id is not None:
                self._finish(db, episode_id, "ok", result, float(cost), "")
            for eid in fed:
                cur = db.execute("UPDATE episodes SET update_idx = ? WHERE episode_id = ? AND run_id = ? "
                                 "AND status = 'ok' AND update_idx IS NULL", (update.idx, eid, update.run_id))
                if cur.rowcount != 1:
                    raise StoreError(f"episode {eid!r} is not an ok episode awaiting update {update.idx}")
            db.execute(
                "INSERT INTO updates VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (update.run_id, update.idx, update.episode_id, _vec(update.theta_before),
                 _vec(update.theta_after), float(update.cost), _opt(update.J), _opt(update.r),
                 _opt(update.r_z), _opt(update.td_error), float(update.kappa), float(update.lr),
                 _dumps(dict(update.state)), update.stamp_s),
            )
            db.execute("UPDATE runs SET updated_s = ? WHERE run_id = ?", (update.stamp_s, update.run_id))

    def interrupt_pending(self, run_id: str, detail: str = "daemon stopped while pending") -> int:
        """Mark every pending attempt of ``run_id`` ``interrupted``; returns how many."""
        with self.transaction() as db:
            cur = db.execute(
                "UPDATE episodes SET status = 'interrupted', detail = ?, finished_s = ? "
                "WHERE run_id = ? AND status = 'pending'", (detail, time.time(), run_id))
            return cur.rowcount

    def attempts(self, run_id: str, status: str | None = None) -> list[EpisodeRecord]:
        """Every attempt of the run in insertion order (optionally one status only)."""
        return [_episode(r) for r in self._rows_of_run("episodes", run_id, "status", status)]

    def ok_episodes(self, run_id: str) -> list[EpisodeRecord]:
        """The run's ok episodes in idx order (idx 0, 1, 2, ...; those of a batch whose
        update is not committed yet have ``update_idx`` None)."""
        rows = self._query("SELECT * FROM episodes WHERE run_id = ? AND status = 'ok' ORDER BY idx",
                           (run_id,))
        return [_episode(r) for r in rows]

    def attempts_of(self, run_id: str, idx: int) -> list[EpisodeRecord]:
        rows = self._query("SELECT * FROM episodes WHERE run_id = ? AND idx = ? ORDER BY attempt",
                           (run_id, idx))
        return [_episode(r) for r in rows]

    def updates(self, run_id: str) -> list[UpdateRecord]:
        rows = self._query("SELECT * FROM updates WHERE run_id = ? ORDER BY idx", (run_id,))
        return [_update(r, self._fed(run_id, r["idx"])) for r in rows]

    def _fed(self, run_id: str, update_idx: int) -> list[str]:
        """The episode ids that fed update ``update_idx`` (none in a schema-2 read-only store)."""
        try:
            rows = self._query("SELECT episode_id FROM episodes WHERE run_id = ? AND update_idx = ? "
                               "ORDER BY idx", (run_id, update_idx))
        except sqlite3.OperationalError:  # read-only open of an older schema
            return []
        return [r[0] for r in rows]

    def update_count(self, run_id: str) -> int:
        return int(self._query("SELECT count(*) FROM updates WHERE run_id = ?", (run_id,))[0][0])

    def last_update(self, run_id: str) -> UpdateRecord | None:
        rows = self._query("SELECT * FROM updates WHERE run_id = ? ORDER BY idx DESC LIMIT 1", (run_id,))
        return _update(rows[0], self._fed(run_id, rows[0]["idx"])) if rows else None

    # ------------------------------------------------------------------ changes
    def record_change(self, run_id: str, kind: str, value: Any, source: str,
                      n_updates: int | None = None) -> ChangeRecord:
        """Record a kappa or theta change (weights: :meth:`record_weights`)."""
        if kind not in ("kappa", "theta"):
            raise StoreError(f"use record_weights for {kind!r}" if kind == "weights" else f"bad kind {kind!r}")
        with self.transaction() as db:
            return self._insert_change(db, run_id, kind, value, source, n_updates)

    def _insert_change(self, db: sqlite3.Connection, run_id: str, kind: str, value: Any,
                       source: str, n_updates: int | None) -> ChangeRecord:
        if n_updates is None:
            n_updates = int(db.execute("SELECT count(*) FROM updates WHERE run_id = ?",
                                       (run_id,)).fetchone()[0])
        cur = db.execute(
            "INSERT INTO changes (run_id, kind, value, source, n_updates, stamp_s) VALUES (?, ?, ?, ?, ?, ?)",
            (run_id, kind, _dumps(value), source, n_updates, time.time()))
        row = db.execute("SELECT * FROM changes WHERE seq = ?", (cur.lastrowid,)).fetchone()
        return _change(row)

    def record_weights(self, run_id: str, weights: Mapping[str, float], source: str,
                       cost_of: Callable[[Mapping[str, float]], float] | None = None) -> ChangeRecord:
        """Record new complete weights and re-cost every ok episode of the run, atomically.

        ``cost = cost_of(cost_terms)`` for every ok episode; ``cost_of`` must use ``weights``
        (default ``TaskSpec.total_cost(terms, weights)``; the daemon passes the learner's own
        combination so the store holds exactly the costs the learner uses).
        """
        run = self.run(run_id)
        spec = get_task(run.task)
        checked = dict(spec.check_weights(weights))
        combine = cost_of if cost_of is not None else (lambda terms: spec.total_cost(terms, checked))
        with self.transaction() as db:
            rows = db.execute("SELECT episode_id, cost_terms FROM episodes WHERE run_id = ? AND status = 'ok'",
                              (run_id,)).fetchall()
            for row in rows:
                cost = float(combine(json.loads(row["cost_terms"])))
                db.execute("UPDATE episodes SET cost = ? WHERE episode_id = ?", (cost, row["episode_id"]))
            return self._insert_change(db, run_id, "weights", checked, source, None)

    def changes(self, run_id: str, kind: str | None = None) -> list[ChangeRecord]:
        """Every change of the run in insertion order (optionally one kind only)."""
        return [_change(r) for r in self._rows_of_run("changes", run_id, "kind", kind)]

    def latest_change(self, run_id: str, kind: str) -> ChangeRecord | None:
        rows = self._query("SELECT * FROM changes WHERE run_id = ? AND kind = ? ORDER BY seq DESC LIMIT 1",
                           (run_id, kind))
        return _change(rows[0]) if rows else None

