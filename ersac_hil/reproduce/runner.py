"""Running the experiments' work on the stack: a pool of simulator/agent pairs, learning runs
(one ``ersac-hil daemon`` process each, its own SQLite store) and trials, with a progress bar.

Every pair is one worker thread; a job is a callable run on a free pair. The pairs are those of
a ``Stack`` (started here) or of ``RemoteAgents`` (already running behind a router, ``reproduce
--agents``): the same jobs, the same requests, the same results. Independent episodes
(trials) spread over every pair; a learning run holds one pair for its whole run (its daemon
talks to that pair's agent, under the pair's key prefix). With one pair everything runs one
episode at a time, as on a single robot.

Resume: a learning run's store holds its episodes (the daemon resumes a run exactly, by run
id); a trial is in the trial store once finished. Re-running a job that is done does nothing.
"""
from __future__ import annotations

import queue
import shutil
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ersac_hil.daemon.agents import AgentLink, Stopped
from ersac_hil.daemon.store import RunRecord, Store
from ersac_hil.stack import ChildFailed, Pair, Stack, cli_argv
from ersac_hil.zenoh_session import open_session, resolve_config
from protocol.zenoh import KeySpace

from .trials import TrialSpec, TrialStore, run_trial

__all__ = ["RunSpec", "Worker", "Pool", "JobFailed", "Progress", "stored_run", "finished", "copy_store", "physics_stack",
           "EPISODE_TIMEOUT_S"]

#: Query timeout of one episode (a 6 s lifting episode takes 1-10 s of wall time under load).
EPISODE_TIMEOUT_S = 120.0
#: Daemon exits (e.g. too many faults under load) after which a learning run is resumed again.
RUN_RETRIES = 3


class JobFailed(RuntimeError):
    """A job could not be completed (the message says which and why)."""


@dataclass(frozen=True)
class RunSpec:
    """One learning run: ``name`` (its store is ``runs/<name>.db``), task, kappa, run seed,
    episode budget, extra daemon flags."""

    name: str
    task: str
    kappa: float
    seed: int
    episodes: int
    extra: tuple[str, ...] = ()

    def db(self, out: Path) -> Path:
        return out / "runs" / f"{self.name}.db"


def physics_stack(logs: Path, stop: threading.Event, say: Callable[[str], None], physics: Path | None,
                  **kwargs: object) -> Stack:
    """A ``Stack`` whose simulators run with ``--physics physics`` (docs/physics.md): a robot
    that differs from its simulator; ``None``: a plain ``Stack``."""
    if physics is None:
        return Stack(logs, stop, say, **kwargs)
    extra = ["--physics", str(Path(physics).resolve())]

    class _PhysicsStack(Stack):
        def launch(self, name: str, argv: list[str], *rest: object, **kw: object) -> object:
            return super().launch(name, [*argv, *extra] if name.startswith("sim") else argv, *rest, **kw)

    return _PhysicsStack(logs, stop, say, **kwargs)


def stored_run(db: Path) -> tuple[RunRecord, int] | None:
    """The run in ``db`` and its ok-episode count, or ``None`` (no store, no run)."""
    if not db.exists():
        return None
    with Store(db, readonly=True) as store:
        runs = store.runs()
        if not runs:
            return None
        run = runs[-1]
        return run, store.update_count(run.run_id)


@dataclass
class Worker:
    """One pair: its agent link (trials) and what it is doing (for the progress line)."""

    pair: Pair
    link: AgentLink
    doing: str = "idle"


class Pool:
    """The pairs of ``stack`` as workers; :meth:`run` runs jobs on free pairs.

    Args:
        stack: a started ``Stack``.
        trials: the trial store.
        stop: set on Ctrl-C; jobs end early, :meth:`run` raises ``Stopped``.
        say: progress lines.
        before_job: called before every job; an exception from it ends the run (no further
            job is started): e.g. ``provenance.guard``.
    """

    def __init__(self, stack: Stack, trials: TrialStore, stop: threading.Event,
                 say: Callable[[str], None] = print, before_job: Callable[[], None] | None = None) -> None:
        self.stack, self.trials, self.stop, self.say = stack, trials, stop, say
        self.before_job = before_job
        self.session = None
        self.workers: list[Worker] = []

    def _start(self) -> None:
        """Start the stack and connect, on the first job (nothing to do: no processes)."""
        if self.session is not None:
            return
        self.stack.start()
        if self.stack.children:  # none when the pairs run elsewhere (``RemoteAgents``)
            self.say("children " + " ".join(f"{c.name}={c.pid}" for c in self.stack.children))
        options = self.stack.zenoh_options()
        self.session = open_session(resolve_config(options), insecure=options.insecure)
        self.workers = [Worker(p, AgentLink(self.session, KeySpace(p.robot, p.prefix), EPISODE_TIMEOUT_S,
                                            self.stop)) for p in self.stack.pairs]

    def close(self) -> None:
        for w in self.workers:
            w.link.wake()
            w.link.close()
        if self.session is not None:
            self.session.close()

    def run(self, jobs: Sequence[tuple[str, Callable[[Worker], None]]]) -> None:
        """Run every ``(label, job)`` on a free worker; returns when all are done. Raises
        ``Stopped`` if interrupted, else ``JobFailed`` naming every failed job."""
        if not jobs:
            return
        self._start()
        todo: queue.Queue = queue.Queue()
        for job in jobs:
            todo.put(job)
        errors: list[str] = []
        halted: list[str] = []

        def work(worker: Worker) -> None:
            while not self.stop.is_set() and not halted:
                try:
                    label, job = todo.get_nowait()
                except queue.Empty:
                    return
                if self.before_job is not None:
                    try:
                        self.before_job()
                    except Exception as exc:  # noqa: BLE001 - no further job starts
                        if not halted:
                            halted.append(str(exc))
                            self.say(f"stopping: {exc}")
                        return
                worker.doing = label
                try:
                    job(worker)
                except Stopped:
                    return
                except Exception as exc:  # noqa: BLE001 - reported together at the end
                    errors.append(f"{label}: {type(exc).__name__}: {exc}")
                    self.say(f"job failed: {label}: {exc}")
                finally:
                    worker.doing = "idle"

        threads = [threading.Thread(target=work, args=(w,), name=f"pair-{w.pair.prefix}", daemon=True)
                   for w in self.workers]
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(0.5)
                self.stack.check()
        if self.stop.is_set():
            raise Stopped
        if halted or errors:
            raise JobFailed("; ".join(halted + errors))

    # ------------------------------------------------------------------ job makers
    def trial_jobs(self, specs: Sequence[TrialSpec], label: str) -> list[tuple[str, Callable[[Worker], None]]]:
        """One job per missing trial of ``specs``."""
        return [(f"{label} {s.task} theta {_short(s.theta)} seed {s.seed}",
                 lambda w, s=s: run_trial(w.link, self.trials, s, self.stop))
                for s in self.trials.missing(specs)]

    def learning_jobs(self, specs: Sequence[RunSpec], out: Path, extra: Sequence[str] = ()
                      ) -> list[tuple[str, Callable[[Worker], None]]]:
        """The jobs that run (or resume) the unfinished runs of ``specs`` until their budget
        is done. ``extra`` flags are added for this invocation only (e.g. ``--episodes``)."""
        return [(f"learning {spec.name}", lambda w, spec=spec: self.learn(w, spec, out, tuple(extra)))
                for spec in specs if not finished(spec, out, extra)]

    def learn(self, worker: Worker, spec: RunSpec, out: Path, extra: Sequence[str] = ()) -> None:
        """Run or resume ``spec`` on ``worker`` until its budget (or ``--episodes`` in ``extra``)
        is done; the daemon is resumed up to ``RUN_RETRIES`` times."""
        db = spec.db(out)
        db.parent.mkdir(parents=True, exist_ok=True)
        extra = tuple(extra)
        budget = _budget(spec, extra)
        for attempt in range(RUN_RETRIES + 1):
            found = stored_run(db)
            if finished(spec, out, extra):
                return
            resume = ("--resume", found[0].run_id) if found is not None else ("--new",)
            code = self.daemon(worker, spec, db, (*resume, *spec.extra, *extra))
            if self.stop.is_set():
                raise Stopped
            found = stored_run(db)
            if code == 0 and found is not None and found[1] >= budget:
                return
            self.say(f"{spec.name}: the daemon exited with {code} "
                     f"({found[1] if found else 0}/{budget} episodes); resuming ({attempt + 1}/{RUN_RETRIES})")
        raise JobFailed(f"{spec.name}: not finished after {RUN_RETRIES} resumes (see logs/daemon-{spec.name}.log)")

    def daemon(self, worker: Worker, spec: RunSpec, db: Path, flags: Sequence[str],
               ready: Callable[[], None] | None = None) -> int:
        """Run ``ersac-hil daemon`` for ``spec`` on ``worker``'s pair until it exits; with
        ``ready`` (a lingering daemon), call it once the daemon is up, then stop the daemon.
        Returns its exit code."""
        pair = worker.pair
        argv = cli_argv("daemon", "--robot", pair.robot, "--prefix", pair.prefix, "--task", spec.task,
                    "--kappa", repr(spec.kappa), "--seed", str(spec.seed), "--episodes", str(spec.episodes),
                    *self.stack.zenoh_args("daemon"), "--db", str(db), "--agent-wait", "600",
                    "--max-attempts", "20", "--episode-timeout", repr(EPISODE_TIMEOUT_S), *flags)
        child = self.stack.launch(f"daemon-{spec.name}", argv)
        try:
            if ready is not None:
                child.wait_for(r"finished: |resumed at episode|run .* finished", 120, self.stop)
                ready()
                return 0
            while child.alive() and not self.stop.is_set():
                time.sleep(0.2)
            return child.proc.wait() if not self.stop.is_set() else 130
        except ChildFailed as exc:
            raise JobFailed(str(exc)) from None
        finally:
            child.stop()
            self.stack.children.remove(child)


def finished(spec: RunSpec, out: Path, extra: Sequence[str] = ()) -> bool:
    """The run of ``spec`` is finished with its budget (or ``--episodes`` in ``extra``)."""
    found = stored_run(spec.db(out))
    return found is not None and found[1] >= _budget(spec, extra) and found[0].status == "finished"


def _budget(spec: RunSpec, extra: Sequence[str]) -> int:
    flags = list(extra)
    if "--episodes" in flags:
        return int(flags[flags.index("--episodes") + 1])
    return spec.episodes


def _short(theta: Sequence[float]) -> str:
    return ",".join(f"{t:.3f}" for t in theta)


def copy_store(src: Path, dst: Path) -> None:
    """A consistent copy of the SQLite store ``src`` (WAL included) at ``dst``."""
    import sqlite3
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_suffix(".tmp")
    tmp.unlink(missing_ok=True)
    with sqlite3.connect(src) as a, sqlite3.connect(tmp) as b:
        a.backup(b)
    shutil.move(tmp, dst)


class Progress:
    """A progress bar over episodes: ``count()`` gives the episodes done so far (from the
    stores, so a resumed run starts where it was); redrawn every second in place on a
    terminal, a line every 5 % (or minute) otherwise."""

    def __init__(self, total: int, count: Callable[[], int], pool: Pool | None = None,
                 out=sys.stdout, width: int = 30) -> None:  # noqa: ANN001
        self.total, self.count, self.pool, self.out, self.width = max(total, 1), count, pool, out, width
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self._done0 = count()
        self._last_line = (-1.0, 0.0)

    def __enter__(self) -> Progress:
        self._thread = threading.Thread(target=self._loop, name="progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.draw(final=True)

    def _loop(self) -> None:
        while not self._stop.wait(1.0):
            self.draw()

    def draw(self, final: bool = False) -> None:
        try:
            done = self.count()
        except Exception:  # noqa: BLE001 - a store being written; next second
            return
        frac = min(done / self.total, 1.0)
        elapsed = time.monotonic() - self._t0
        rate = (done - self._done0) / elapsed if elapsed > 0 else 0.0
        left = f"~{_clock((self.total - done) / rate)} left" if rate > 0 and done < self.total else ""
        doing = ""
        if self.pool is not None:
            doing = " | " + "; ".join(w.doing for w in self.pool.workers)
        bar = "#" * int(frac * self.width) + "." * (self.width - int(frac * self.width))
        line = f"[{bar}] {done}/{self.total} episodes {100 * frac:5.1f} % {_clock(elapsed)} {left}{doing}"
        if getattr(self.out, "isatty", lambda: False)():
            self.out.write("\r" + line[:160].ljust(160) + ("\n" if final else ""))
            self.out.flush()
            return
        pct, stamp = self._last_line
        if final or frac - pct >= 0.05 or time.monotonic() - stamp >= 60:
            self._last_line = (frac, time.monotonic())
            print(line, file=self.out, flush=True)


def _clock(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    return f"{seconds // 3600:d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
