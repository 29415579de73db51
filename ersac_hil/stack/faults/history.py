"""What a faulted run's store holds, and how it compares with the run without the fault."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ersac_hil.daemon.store import Store

__all__ = ["History", "Tally", "history", "n_ok", "tally"]


@dataclass(frozen=True)
class History:
    """A run as its store holds it. ``episodes``: the ok episodes as (idx, theta, seed, cost
    terms, update idx) in store order; ``updates``: (idx, theta before, theta after, J, r,
    state, idx of the episodes that fed it); ``attempts``: (idx, attempt, status) of every
    attempt; ``finished``: the ``finished_s`` wall times of the ok episodes."""

    status: str
    episodes: tuple
    updates: tuple
    attempts: tuple
    finished: tuple[float, ...]


def history(db: Path) -> History | None:
    """The store's one run, or ``None`` while it has none (or is being created)."""
    if not db.exists():
        return None
    try:
        with Store(db, readonly=True) as store:
            runs = store.runs()
            if not runs:
                return None
            (run,) = runs
            attempts = store.attempts(run.run_id)
            ok = [a for a in attempts if a.ok]
            idx_of = {e.episode_id: e.idx for e in ok}
            return History(
                run.status,
                tuple((e.idx, e.theta, e.seed, tuple(sorted(e.cost_terms.items())), e.update_idx) for e in ok),
                tuple((u.idx, u.theta_before, u.theta_after, u.J, u.r, repr(sorted(u.state.items())),
                       tuple(idx_of[i] for i in u.episodes)) for u in store.updates(run.run_id)),
                tuple((a.idx, a.attempt, a.status) for a in attempts),
                tuple(e.finished_s for e in ok))
    except Exception:  # noqa: BLE001 - the writer may be creating the schema right now
        return None


def n_ok(db: Path) -> int:
    h = history(db)
    return len(h.episodes) if h else 0


@dataclass(frozen=True)
class Tally:
    """A faulted run against the run without the fault: episodes of the reference missing
    (``lost``), idx recorded ok more than once (``duplicated``), idx whose request or costs
    differ (``differing``), updates that differ."""

    lost: int
    duplicated: int
    differing: int
    updates_differing: int

    @property
    def exact(self) -> bool:
        return not (self.lost or self.duplicated or self.differing or self.updates_differing)


def tally(reference: History, run: History) -> Tally:
    ref = {e[0]: e for e in reference.episodes}
    got: dict[int, list[tuple]] = {}
    for e in run.episodes:
        got.setdefault(e[0], []).append(e)
    ref_updates = dict((u[0], u) for u in reference.updates)
    return Tally(lost=sum(idx not in got for idx in ref),
                 duplicated=sum(len(v) - 1 for v in got.values()),
                 differing=sum(idx in ref and v[0] != ref[idx] for idx, v in got.items()),
                 updates_differing=sum(ref_updates.get(u[0]) != u for u in run.updates)
                 + sum(i not in {u[0] for u in run.updates} for i in ref_updates))
