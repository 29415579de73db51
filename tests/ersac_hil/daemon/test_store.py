"""The SQLite store, real files in tmp_path: WAL, commit per episode, re-costing, resume queries."""
from __future__ import annotations

import dataclasses
import math
import sqlite3
import subprocess
import sys
import textwrap

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.daemon.store import SCHEMA_VERSION, Store, StoreError, UpdateRecord
from protocol.zenoh import EpisodeResult, get_task
from protocol.zenoh.tasks import weighted_total

SPEC = get_task("bracing")


def _result(eid: str, terms: dict[str, float], status: str = "ok") -> EpisodeResult:
    total = SPEC.total_cost(terms) if status == "ok" else None
    return EpisodeResult(eid, "bracing", status, terms, total, failures={"fallen": False},
                         duration_s=2.0, wall_s=0.5, telemetry={"n_cycles": 400.0, "energy_j": 3.5},
                         fault_counts={"emcy": 0})


def _update(run_id: str, idx: int, eid: str, before: float, after: float) -> UpdateRecord:
    return UpdateRecord(run_id=run_id, idx=idx, episode_id=eid, theta_before=(before,),
                        theta_after=(after,), cost=1.5, J=1.2, r=0.3, r_z=0.35, td_error=0.1,
                        kappa=2.0, lr=0.2, state={"rng": {"state": 12345678901234567890123}, "note": "x"},
                        stamp_s=1000.0 + idx)


def _ok_episode(store: Store, run_id: str, idx: int, terms: dict[str, float], attempt: int = 0) -> str:
    eid = f"{run_id}.{idx:05d}.{attempt}"
    store.begin_attempt(run_id, eid, idx, attempt, (0.5,), (0.01,), (0.51,), 7 + idx)
    result = _result(eid, terms)
    store.record_success(eid, result, SPEC.total_cost(terms), _update(run_id, idx, eid, 0.5, 0.52))
    return eid


@pytest.fixture
def store(tmp_path):
    with Store(tmp_path / "s.db") as s:
        s.create_run("run1", "r1", "bracing", 42, {"kappa": 2.0, "theta0": [0.5]})
        yield s


def test_store_is_wal_with_schema_and_reopens(tmp_path):
    path = tmp_path / "sub" / "x.db"
    with Store(path) as s:
        assert s.journal_mode == "wal"
        s.create_run("a", "r1", "bracing", 1, {"k": 1})
    with Store(path) as s:  # reopening keeps the data, no re-creation
        assert [r.run_id for r in s.runs()] == ["a"]
        assert s.run("a").settings == {"k": 1}
    with Store(path, readonly=True) as s:
        assert s.run("a").seed == 1


def test_foreign_sqlite_files_are_refused(tmp_path):
    path = tmp_path / "other.db"
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="not an ersac-hil store"):
        Store(path)
    (tmp_path / "junk.db").write_bytes(b"not a database at all" * 100)
    with pytest.raises(StoreError):
        Store(tmp_path / "junk.db")
    with pytest.raises(StoreError, match="no store"):
        Store(tmp_path / "missing.db", readonly=True)


def test_duplicate_run_is_refused(store):
    with pytest.raises(StoreError, match="exists"):
        store.create_run("run1", "r1", "bracing", 1, {})


def test_each_episode_is_visible_to_another_connection_once_recorded(store, tmp_path):
    """Commit per episode: a separate reader (another connection) sees the pending attempt
    and then the ok episode together with its update, never one without the other."""
    reader = sqlite3.connect(tmp_path / "s.db")
    eid = "run1.00000.0"
    store.begin_attempt("run1", eid, 0, 0, (0.5,), (0.01,), (0.51,), 7)
    assert reader.execute("SELECT status FROM episodes").fetchall() == [("pending",)]
    assert reader.execute("SELECT count(*) FROM updates").fetchone() == (0,)
    terms = {"damage": 0.0, "body_acc_sq": 2.5, "arm_power": 0.25}
    store.record_success(eid, _result(eid, terms), SPEC.total_cost(terms), _update("run1", 0, eid, 0.5, 0.55))
    assert reader.execute("SELECT status, cost FROM episodes").fetchall() == [("ok", SPEC.total_cost(terms))]
    assert reader.execute("SELECT theta_after FROM updates").fetchall() == [("[0.55]",)]
    reader.close()
    ep = store.ok_episodes("run1")[0]
    assert ep.cost_terms == terms and ep.telemetry["energy_j"] == 3.5 and ep.seed == 7
    up = store.last_update("run1")
    assert up.state["rng"]["state"] == 12345678901234567890123  # big ints survive


def test_success_and_update_are_one_transaction(store):
    eid = "run1.00000.0"
    store.begin_attempt("run1", eid, 0, 0, (0.5,), (0.0,), (0.5,), 1)
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0}
    bad = _update("run1", 0, "run1.99999.0", 0.5, 0.5)  # refers to an unknown episode
    with pytest.raises(StoreError):
        store.record_success(eid, _result(eid, terms), 1.0, bad)
    broken = dataclasses.replace(_update("run1", 0, eid, 0.5, 0.5), cost=math.nan)
    with pytest.raises(sqlite3.IntegrityError):  # NaN cost -> NOT NULL violation -> rollback
        store.record_success(eid, _result(eid, terms), 1.0, broken)
    assert [e.status for e in store.attempts("run1")] == ["pending"]
    assert store.updates("run1") == []


def test_failed_attempts_are_kept_and_only_one_ok_per_index(store):
    store.begin_attempt("run1", "a0", 0, 0, (0.5,), (0.0,), (0.5,), 1)
    store.record_failure("a0", "fault_emcy", "EMCY 0x5000", _result("a0", {"damage": 1.0}, "fault_emcy"))
    store.begin_attempt("run1", "a1", 0, 1, (0.5,), (0.0,), (0.5,), 1)
    store.record_failure("a1", "timeout", "no reply within 60 s")
    _ok_episode(store, "run1", 0, {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0}, attempt=2)
    assert [(e.attempt, e.status) for e in store.attempts_of("run1", 0)] == [
        (0, "fault_emcy"), (1, "timeout"), (2, "ok")]
    assert store.attempts_of("run1", 0)[0].cost_terms == {"damage": 1.0}
    # a second ok for the same index is impossible, whatever the attempt number
    store.begin_attempt("run1", "dup", 0, 3, (0.5,), (0.0,), (0.5,), 1)
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0}
    with pytest.raises(sqlite3.IntegrityError):
        store.record_success("dup", _result("dup", terms), 1.0, _update("run1", 0, "dup", 0.5, 0.5))
    with pytest.raises(StoreError):  # same attempt number twice
        store.begin_attempt("run1", "again", 0, 3, (0.5,), (0.0,), (0.5,), 1)
    with pytest.raises(StoreError, match="not pending"):
        store.record_failure("a0", "timeout", "twice")
    assert store.interrupt_pending("run1") == 1
    assert store.attempts_of("run1", 0)[-1].status == "interrupted"


def test_a_killed_writer_leaves_only_whole_episodes(tmp_path):
    """A process SIGKILLed in a loop of record_success leaves every episode with its update."""
    path = tmp_path / "k.db"
    code = textwrap.dedent(f"""
        import os, signal
        from ersac_hil.daemon.store import Store, UpdateRecord
        from protocol.zenoh import EpisodeResult, get_task
        spec = get_task("bracing")
        s = Store({str(path)!r})
        s.create_run("k", "r1", "bracing", 1, {{}})
        terms = {{"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0}}
        for i in range(10**6):
            eid = f"k.{{i}}"
            s.begin_attempt("k", eid, i, 0, (0.5,), (0.0,), (0.5,), i)
            if i == 40:
                os.kill(os.getpid(), signal.SIGKILL)
            r = EpisodeResult(eid, "bracing", "ok", terms, spec.total_cost(terms))
            s.record_success(eid, r, 1.0, UpdateRecord(run_id="k", idx=i, episode_id=eid, theta_before=(0.5,), theta_after=(0.5,), cost=1.0, J=None, r=None, r_z=None, td_error=None, kappa=0.0, lr=0.1, state={{}}, stamp_s=0.0))
    """)
    proc = subprocess.run([sys.executable, "-c", code], timeout=60)
    assert proc.returncode == -9
    with Store(path) as s:
        ok = s.ok_episodes("k")
        assert [e.idx for e in ok] == list(range(40))
        assert [u.idx for u in s.updates("k")] == list(range(40))
        assert [e.status for e in s.attempts_of("k", 40)] == ["pending"]


def test_a_write_the_disk_refuses_is_store_unwritable_and_leaves_the_store_whole(tmp_path):
    """Once no file of the writer may grow (RLIMIT_FSIZE 0, the full disk: SQLite's disk I/O
    error), every write raises ``StoreUnwritable`` naming the store, nothing of it is stored,
    and the store opens afterwards with what was committed before."""
    path = tmp_path / "f.db"
    code = textwrap.dedent(f"""
        import resource
        from ersac_hil.daemon.store import Store, StoreUnwritable, UpdateRecord
        from protocol.zenoh import EpisodeResult
        terms = {{"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0}}
        s = Store({str(path)!r})
        s.create_run("f", "r1", "bracing", 1, {{}})
        def episode(i):
            eid = f"f.{{i}}"
            s.begin_attempt("f", eid, i, 0, (0.5,), (0.0,), (0.5,), i)
            s.record_success(eid, EpisodeResult(eid, "bracing", "ok", terms, 1.0), 1.0, UpdateRecord(run_id="f", idx=i, episode_id=eid, theta_before=(0.5,), theta_after=(0.5,), cost=1.0, J=None, r=None, r_z=None, td_error=None, kappa=0.0, lr=0.1, state={{}}, stamp_s=0.0))
        for i in range(3):
            episode(i)
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))
        for i in range(3, 6):  # each write refused, the connection still usable for the next
            try:
                episode(i)
            except StoreUnwritable as exc:
                print(exc)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 3 and all(line == f"store {path} cannot be written: disk I/O error; is the disk full?"
                                   for line in lines), proc.stdout
    with Store(path) as s:
        assert [e.idx for e in s.attempts("f")] == [0, 1, 2] and [u.idx for u in s.updates("f")] == [0, 1, 2]


_term = st.floats(0.0, 1e6, allow_nan=False, allow_infinity=False)
_weight = st.floats(0.0, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    terms=st.lists(st.fixed_dictionaries({"damage": st.sampled_from([0.0, 1.0]),
                                          "body_acc_sq": _term, "arm_power": _term}),
                   min_size=1, max_size=6),
    weights=st.fixed_dictionaries({"damage": _weight, "body_acc_sq": _weight, "arm_power": _weight}),
)
def test_recosting_is_exact(tmp_path_factory, terms, weights):
    path = tmp_path_factory.mktemp("recost") / "r.db"
    with Store(path) as s:
        s.create_run("w", "r1", "bracing", 1, {})
        for i, t in enumerate(terms):
            _ok_episode(s, "w", i, t)
        s.begin_attempt("w", "failed", len(terms), 0, (0.5,), (0.0,), (0.5,), 1)
        s.record_failure("failed", "fault_heartbeat", "lost heartbeat")
        change = s.record_weights("w", weights, "test")
        assert change.kind == "weights" and change.value == weights and change.n_updates == len(terms)
        for ep, t in zip(s.ok_episodes("w"), terms):
            expected = weighted_total(t, weights)  # the contract's one sum
            assert ep.cost == expected  # exact, not approx
            assert ep.cost_terms == t  # raw terms never change
        assert s.attempts("w", "fault_heartbeat")[0].cost is None
        assert s.latest_change("w", "weights").value == weights


def test_bad_weights_change_nothing(store):
    _ok_episode(store, "run1", 0, {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 1.0})
    before = store.ok_episodes("run1")[0].cost
    for bad in ({"damage": 1.0}, {"damage": -1.0, "body_acc_sq": 1.0, "arm_power": 1.0},
                {"damage": 1.0, "body_acc_sq": 1.0, "arm_power": 1.0, "extra": 1.0}):
        with pytest.raises(ValueError):
            store.record_weights("run1", bad, "test")
    assert store.ok_episodes("run1")[0].cost == before
    assert store.changes("run1") == []


def test_changes_and_latest_unfinished(store):
    store.record_change("run1", "kappa", 0.5, "control")
    store.record_change("run1", "kappa", 1.5, "control")
    store.record_change("run1", "theta", [0.3], "select")
    assert [c.value for c in store.changes("run1", "kappa")] == [0.5, 1.5]
    assert store.latest_change("run1", "kappa").value == 1.5
    assert store.latest_change("run1", "theta").n_updates == 0
    with pytest.raises(StoreError):
        store.record_change("run1", "weights", {}, "x")
    store.create_run("run2", "r1", "bracing", 2, {})
    store.create_run("run3", "r1", "lifting", 3, {})
    assert store.latest_unfinished("r1", "bracing").run_id == "run2"
    store.set_run_status("run2", "finished")
    assert store.latest_unfinished("r1", "bracing").run_id == "run1"
    assert store.latest_unfinished("r2", "bracing") is None
    with pytest.raises(StoreError):
        store.set_run_status("run1", "exploded")


def test_trace_names_are_stored_and_a_schema_1_store_is_migrated(tmp_path):
    path = tmp_path / "old.db"
    with Store(path) as store:
        store.create_run("r1", "ubot1", "bracing", 3, {"episodes": 2})
        eid = _ok_episode(store, "r1", 0, {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 0.5})
    db = sqlite3.connect(path)  # what a schema-1 store looks like: no trace column
    db.executescript("ALTER TABLE episodes DROP COLUMN trace; ALTER TABLE episodes DROP COLUMN update_idx; "
                     "ALTER TABLE episodes DROP COLUMN mcap; PRAGMA user_version = 1;")
    db.close()
    with Store(path, readonly=True) as store:
        assert [e.trace for e in store.ok_episodes("r1")] == [""]
    with Store(path) as store:  # migrated on a read-write open
        assert store.journal_mode == "wal"
        eid = "r1.00001.0"
        store.begin_attempt("r1", eid, 1, 0, (0.5,), (0.01,), (0.51,), 8)
        terms = {"damage": 0.0, "body_acc_sq": 2.0, "arm_power": 0.5}
        traced = EpisodeResult(eid, "bracing", "ok", terms, SPEC.total_cost(terms), trace=f"{eid}.blf")
        store.record_success(eid, traced, SPEC.total_cost(terms), _update("r1", 1, eid, 0.5, 0.52))
        assert [e.trace for e in store.ok_episodes("r1")] == ["", f"{eid}.blf"]
    assert sqlite3.connect(path).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 4


def test_a_schema_2_store_is_migrated_in_place_and_keeps_everything(tmp_path):
    """Schema 2 -> 3: every update of the time had one episode; ``update_idx`` is filled from
    the updates, nothing else changes, and the run goes on with batches."""
    path = tmp_path / "v2.db"
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 0.5}
    with Store(path) as store:
        store.create_run("r1", "ubot1", "bracing", 3, {"episodes": 5})
        eids = [_ok_episode(store, "r1", i, terms) for i in range(3)]
        store.begin_attempt("r1", "r1.00003.0", 3, 0, (0.5,), (0.01,), (0.51,), 10)
        store.record_failure("r1.00003.0", "timeout", "no reply")
        before = (store.attempts("r1"), store.updates("r1"))
    db = sqlite3.connect(path)  # what a schema-2 store looks like: no update_idx column
    db.executescript("ALTER TABLE episodes DROP COLUMN update_idx; ALTER TABLE episodes DROP COLUMN mcap; "
                     "PRAGMA user_version = 2;")
    db.close()
    with Store(path, readonly=True) as store:  # read as it is
        assert [e.update_idx for e in store.ok_episodes("r1")] == [None] * 3
        assert [u.episodes for u in store.updates("r1")] == [(e,) for e in eids]
    with Store(path) as store:  # migrated on a read-write open
        assert (store.attempts("r1"), store.updates("r1")) == before
        assert [e.update_idx for e in store.ok_episodes("r1")] == [0, 1, 2]
        # the run goes on with a batch of two: two ok episodes, one update
        for i in (4, 5):
            eid = f"r1.{i:05d}.0"
            store.begin_attempt("r1", eid, i, 0, (0.5,), (0.01,), (0.51,), 7 + i)
        store.record_ok("r1.00004.0", _result("r1.00004.0", terms), 1.0)
        update = dataclasses.replace(_update("r1", 3, "r1.00005.0", 0.5, 0.52),
                                     episodes=("r1.00004.0", "r1.00005.0"))
        store.record_success("r1.00005.0", _result("r1.00005.0", terms), 1.0, update)
        assert store.updates("r1")[-1].episodes == ("r1.00004.0", "r1.00005.0")
        assert [e.update_idx for e in store.ok_episodes("r1")] == [0, 1, 2, 3, 3]
    assert sqlite3.connect(path).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def test_mcap_names_are_stored_and_a_schema_3_store_is_migrated_in_place(tmp_path):
    """Schema 3 -> 4: ``episodes.mcap`` (the agent's MCAP file of the episode), empty for the
    episodes of the time; nothing else changes and the run goes on."""
    path = tmp_path / "v3.db"
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 0.5}
    with Store(path) as store:
        store.create_run("r1", "ubot1", "bracing", 3, {"episodes": 5})
        for i in range(2):
            _ok_episode(store, "r1", i, terms)
        before = (store.attempts("r1"), store.updates("r1"))
    db = sqlite3.connect(path)  # what a schema-3 store looks like: no mcap column
    db.executescript("ALTER TABLE episodes DROP COLUMN mcap; PRAGMA user_version = 3;")
    db.close()
    with Store(path, readonly=True) as store:  # read as it is
        assert [e.mcap for e in store.ok_episodes("r1")] == ["", ""]
        assert (store.attempts("r1"), store.updates("r1")) == before
    assert sqlite3.connect(path).execute("PRAGMA user_version").fetchone()[0] == 3
    with Store(path) as store:  # migrated on a read-write open
        assert (store.attempts("r1"), store.updates("r1")) == before
        eid = "r1.00002.0"
        store.begin_attempt("r1", eid, 2, 0, (0.5,), (0.01,), (0.51,), 9)
        recorded = EpisodeResult(eid, "bracing", "ok", terms, SPEC.total_cost(terms), trace=f"{eid}.blf",
                                 mcap=f"{eid}.mcap")
        store.record_success(eid, recorded, SPEC.total_cost(terms), _update("r1", 2, eid, 0.5, 0.52))
        assert [(e.trace, e.mcap) for e in store.ok_episodes("r1")] == [("", ""), ("", ""),
                                                                       (f"{eid}.blf", f"{eid}.mcap")]
    assert sqlite3.connect(path).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 4


def test_an_update_takes_only_ok_episodes_awaiting_it(store):
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 0.5}
    for i in range(3):
        store.begin_attempt("run1", f"run1.{i:05d}.0", i, 0, (0.5,), (0.01,), (0.51,), 7 + i)
    store.record_ok("run1.00000.0", _result("run1.00000.0", terms), 1.0)
    bad = [("run1.00001.0", "run1.00002.0"),  # 00001 is still pending
           ("run1.00000.0", "run1.00000.0", "run1.00002.0")]  # one episode twice
    for fed in bad:
        update = dataclasses.replace(_update("run1", 0, "run1.00002.0", 0.5, 0.52), episodes=fed)
        with pytest.raises(StoreError):
            store.record_success("run1.00002.0", _result("run1.00002.0", terms), 1.0, update)
        assert store.updates("run1") == [] and [a.status for a in store.attempts("run1")] == ["ok", "pending", "pending"]
    with pytest.raises(StoreError):  # the update's episode_id must be the last of its episodes
        store.record_success("run1.00002.0", _result("run1.00002.0", terms), 1.0, dataclasses.replace(
            _update("run1", 0, "run1.00000.0", 0.5, 0.52), episodes=("run1.00000.0", "run1.00002.0")))
    update = dataclasses.replace(_update("run1", 0, "run1.00002.0", 0.5, 0.52),
                                 episodes=("run1.00000.0", "run1.00002.0"))
    store.record_success("run1.00002.0", _result("run1.00002.0", terms), 1.0, update)
    assert [(a.status, a.update_idx) for a in store.attempts("run1")] == [("ok", 0), ("pending", None), ("ok", 0)]


def test_a_store_whose_status_check_predates_a_status_is_rebuilt_and_keeps_everything(tmp_path):
    """A store created before an attempt status existed (here: ``stopped``, the e-stop's) has a
    CHECK that refuses it, which ``ALTER TABLE`` cannot change: a read-write open rebuilds the
    table once with today's definition, every row kept; a read-only open leaves the file alone."""
    from ersac_hil.daemon import store as store_module
    path = tmp_path / "old-check.db"
    terms = {"damage": 0.0, "body_acc_sq": 1.0, "arm_power": 0.5}
    old_schema = store_module._SCHEMA.replace("'stopped', ", "")
    assert old_schema != store_module._SCHEMA
    db = sqlite3.connect(path)
    db.executescript(old_schema)
    db.close()
    with Store(path, readonly=True) as store:
        assert store.attempts("r1") == []
    assert "'stopped'" not in sqlite3.connect(path).execute(
        "SELECT sql FROM sqlite_master WHERE name = 'episodes'").fetchone()[0]
    with Store(path) as store:
        store.create_run("r1", "ubot1", "bracing", 3, {"episodes": 5})
        for i in range(2):
            _ok_episode(store, "r1", i, terms)
        store.begin_attempt("r1", "r1.00002.0", 2, 0, (0.5,), (0.01,), (0.51,), 9)
        before = (store.attempts("r1"), store.updates("r1"))
    db = sqlite3.connect(path)  # back to the old definition, rows and all
    db.executescript("PRAGMA foreign_keys = OFF; BEGIN;"
                     + store_module._episodes_sql().replace("CREATE TABLE episodes", "CREATE TABLE old", 1)
                     .replace("'stopped', ", "") + "; INSERT INTO old SELECT * FROM episodes; DROP TABLE episodes;"
                     " ALTER TABLE old RENAME TO episodes;" + store_module._episodes_indexes() + " COMMIT;")
    db.close()
    with pytest.raises(sqlite3.IntegrityError):  # what the old CHECK does to an e-stopped attempt
        raw = sqlite3.connect(path)
        raw.execute("UPDATE episodes SET status = 'stopped' WHERE episode_id = 'r1.00002.0'")
    raw.close()
    with Store(path) as store:
        assert (store.attempts("r1"), store.updates("r1")) == before
        store.record_failure("r1.00002.0", "stopped", "e-stop")
        assert [a.status for a in store.attempts("r1")] == ["ok", "ok", "stopped"]
        store.begin_attempt("r1", "r1.00002.1", 2, 1, (0.5,), (0.01,), (0.51,), 10)
        assert store.attempts("r1")[-1].seq > store.attempts("r1")[-2].seq
    stored = sqlite3.connect(path).execute("SELECT sql FROM sqlite_master WHERE name = 'episodes'").fetchone()[0]
    assert store_module._definition(stored) == store_module._definition(store_module._episodes_sql())
    page = "SELECT rootpage FROM sqlite_master WHERE name = 'episodes'"
    rootpage = sqlite3.connect(path).execute(page).fetchone()[0]
    with Store(path) as store:  # today's definition: left as it is (a rebuild moves the table)
        assert [a.status for a in store.attempts("r1")] == ["ok", "ok", "stopped", "pending"]
    assert sqlite3.connect(path).execute(page).fetchone()[0] == rootpage
