"""``ersac-hil reproduce`` (picked up by ``ersac_hil.cli``): argument parsing, the stack's
lifetime, the experiments in order, the analysis and the results files.

Exit codes: 0 done (whether or not the targets are met: results.md says), 1 a job failed (the
run stays resumable), 2 invalid arguments or an output directory that does not fit
(``planfile``: other sizes asked for, other episode code, learning runs of other learner
code), 128+N after signal N (resumable).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from ersac_hil.cli_args import output_dir
from ersac_hil.stack import PAIRS_PER_CORE, TooManyPairs, check_pairs

if TYPE_CHECKING:
    from ersac_hil.stack.remote import Agents

__all__ = ["register", "run_reproduce"]

EXPERIMENTS = ("bracing", "lifting", "contexts")


def _count(out: Path, sizes, experiments) -> tuple[int, Callable[[], int]]:  # noqa: ANN001
    """(total episodes, a function counting the episodes done so far) of ``experiments``: the
    learning episodes of their runs and their stored trials (those known so far: test trials
    are known once the run they test is done), not whatever else the trial store holds."""
    from . import bracing, contexts, lifting, plan
    from .runner import stored_run

    modules = {"bracing": bracing, "lifting": lifting, "contexts": contexts}
    runs, context_runs, trials = [], [], 0
    if "bracing" in experiments:
        trials += len({s.key for s in bracing.known_trials(sizes, out)})
        runs += plan.bracing_runs(sizes)
    if "lifting" in experiments or "contexts" in experiments:
        runs += plan.lifting_runs(sizes) if "lifting" in experiments else plan.lifting_runs(sizes)[:1]
    if "lifting" in experiments:
        trials += 3 * sizes.test_trials * sizes.lifting_seeds
    if "contexts" in experiments:
        context_runs = [spec for _, spec in plan.context_runs(sizes)]
        # per context: selected, after; the prior column is one (the lifting run's last stage)
        trials += sizes.test_trials * (2 * len(context_runs) + (0 if "lifting" in experiments else 1))
    total = trials + sum(r.episodes for r in runs) + len(context_runs) * sizes.context_episodes

    def count() -> int:
        from .trials import TrialStore
        keys = {s.key for name in experiments for s in modules[name].known_trials(sizes, out)}
        with TrialStore(out / "trials.db") as store:
            done = store.count(keys)
        for r in runs:
            found = stored_run(r.db(out))
            done += found[1] if found else 0
        for r in context_runs:
            found = stored_run(r.db(out))
            done += max(0, found[1] - sizes.lifting_episodes) if found else 0
        return done
    return total, count


def _plan(out: Path, experiments, requested, explicit):  # noqa: ANN001, ANN202
    """``planfile.resolve`` on ``out``'s ``plan.json``; writes the new record and returns the
    ``Resolved`` sizes, or raises ``PlanConflict`` (nothing written)."""
    from .planfile import resolve
    from .provenance import LEARNING, fingerprint
    path = out / "plan.json"
    recorded = json.loads(path.read_text()) if path.exists() else None
    existing = {p.stem for p in (out / "runs").glob("*.db")}
    resolved = resolve(recorded, experiments, requested, explicit, fingerprint(), fingerprint(LEARNING), existing)
    path.write_text(json.dumps(resolved.record, indent=1) + "\n")
    return resolved


def run_reproduce(experiment: str, sizes, out: Path, pairs: int, stop: threading.Event,  # noqa: ANN001
                  say: Callable[[str], None] = print, explicit: Collection[str] | None = None,
                  agents: Agents | None = None) -> int:
    """Run ``experiment`` (or ``all``) with ``sizes`` (``explicit``: the fields asked for by an
    option, default all; the others as ``out`` recorded them for each experiment where it did),
    analyse, write the results. With ``agents`` the pairs are the agents already running behind
    a router that it finds (``pairs`` is ignored; none found: refused, nothing written), else
    ``pairs`` pairs are started here. Returns an exit code."""
    from ersac_hil.daemon.agents import Stopped
    from ersac_hil.daemon.discovery import NoAgents, reach_agents
    from ersac_hil.stack import ChildFailed, Stack
    from ersac_hil.stack.remote import RemoteAgents

    from . import bracing, contexts, lifting, results
    from .planfile import INTERLEAVE, SIZE_FIELDS, PlanConflict
    from .provenance import LEARNING, fingerprint, guard
    from .runner import JobFailed, Pool, Progress
    from .trials import TrialStore

    modules = {"bracing": bracing, "lifting": lifting, "contexts": contexts}
    experiments = EXPERIMENTS if experiment == "all" else (experiment,)
    robots: list[str] = []
    if agents is not None:
        try:
            robots = reach_agents(agents.options, agents.source, agents.prefix, agents.wait_s, stop)
        except NoAgents as exc:
            print(f"ersac-hil reproduce: --agents {agents.source}: {exc}", file=sys.stderr)
            return 2
        except Stopped:
            return 130
        pairs = len(robots)
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    try:
        resolved = _plan(out, experiments, sizes, SIZE_FIELDS | {INTERLEAVE} if explicit is None else explicit)
    except PlanConflict as exc:
        print(f"ersac-hil reproduce: {out} {exc}", file=sys.stderr)
        return 2
    sizes = resolved.sizes
    code = {**resolved.record["model"], **fingerprint(LEARNING)}  # what the guard watches
    # per experiment: what each recorded experiment was made with (not only this invocation's)
    meta = {"sizes": resolved.record["experiments"], "quick": resolved.quick, "model": resolved.record["model"]}
    report = results.load(out)
    timing = report.get("meta", {}).get("timing", {})
    total, count = _count(out, sizes, experiments)
    where = (f"{pairs} agent(s) behind the router ({', '.join(robots)})" if agents is not None
             else f"{pairs} simulator/agent pair(s)")
    say(f"reproduce {experiment}: {total} episodes to have ({count()} already stored) on {where}; output in {out}")
    stack_say = lambda line: say(f"reproduce: {line}")  # noqa: E731
    stack = (RemoteAgents(out / "logs", stop, stack_say, robots, agents.prefix, agents.options)
             if agents is not None else Stack(out / "logs", stop, stack_say, pairs=pairs))
    trials = TrialStore(out / "trials.db")
    pool = Pool(stack, trials, stop, say, before_job=guard(code))
    try:
        with Progress(total, count, pool):
            for name in experiments:
                load0, t0 = os.getloadavg()[0], time.monotonic()
                modules[name].execute(pool, sizes, out)
                timing[name] = {"wall_s": time.monotonic() - t0, "load_start": load0,
                                "load_end": os.getloadavg()[0]}
    except (Stopped, ChildFailed) as exc:
        if stop.is_set():
            say("reproduce: interrupted; run the same command again to resume")
            return 130
        say(f"reproduce: {exc}")
        return 1
    except JobFailed as exc:
        say(f"reproduce: {exc}; run the same command again to resume")
        return 1
    finally:
        pool.close()
        stack.close()
    say("reproduce: all episodes done; analysing")
    try:
        for name in experiments:
            report[name] = modules[name].analyse(sizes, out, trials, say)
    finally:
        trials.close()
    report["meta"] = {**meta, "pairs": pairs, "timing": timing,
                      **({"agents": {"source": agents.source, "robots": robots}} if agents is not None else {})}
    results.save(out, report)
    met = [t for t in report["targets"] if t["met"]]
    say(f"reproduce: {len(met)}/{len(report['targets'])} targets met; {out / 'results.md'}")
    return 0


def _main(args: argparse.Namespace) -> int:
    from .plan import FULL, QUICK
    from .planfile import INTERLEAVE, SIZE_FIELDS

    if args.seeds is not None and args.seeds < 1:
        print("ersac-hil reproduce: --seeds must be >= 1", file=sys.stderr)
        return 2
    from ersac_hil.stack.remote import agents_from_args

    agents, refusal = agents_from_args(args)
    if refusal:
        print(f"ersac-hil reproduce: {refusal}", file=sys.stderr)
        return 2
    pairs = 1 if args.pairs is None else args.pairs
    if pairs < 1:
        print("ersac-hil reproduce: --pairs must be >= 1", file=sys.stderr)
        return 2
    if not args.oversubscribe:
        try:
            check_pairs(pairs, "--pairs", "--oversubscribe")
        except TooManyPairs as exc:
            print(f"ersac-hil reproduce: {exc}", file=sys.stderr)
            return 2
    if args.lifting_interleave is not None and not 0 <= args.lifting_interleave <= 1000:
        print("ersac-hil reproduce: --lifting-interleave must be in 0..1000 (0: the paper's Algorithm 1)",
              file=sys.stderr)
        return 2
    sizes = (QUICK if args.quick else FULL).with_seeds(args.seeds)
    explicit: set[str] = set(SIZE_FIELDS) if args.quick or args.seeds is not None else set()
    if args.lifting_interleave is not None:
        sizes = replace(sizes, lifting_interleave_every=args.lifting_interleave)
        explicit.add(INTERLEAVE)
    from ersac_hil.lifecycle import until_signal
    return until_signal(lambda stop: run_reproduce(args.experiment, sizes, Path(args.out), pairs, stop,
                                                   lambda line: print(line, flush=True), explicit, agents))


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``reproduce`` to the ``ersac-hil`` parser."""
    from ersac_hil.stack.remote import add_agents_arguments

    p = sub.add_parser("reproduce", help="the paper's experiments through the real stack; figures and results",
                       description="The paper's experiments (Figs. 1, 2, 4, 6 and their statistics) through the "
                       "real stack, the processes of the demo: Zenoh router, per simulator/agent pair a "
                       "simulator and an agent talking CAN (over Zenoh by default), one daemon per learning "
                       "run; resumable. Without --seeds/--quick an output directory's recorded sizes are "
                       "taken over per experiment.")
    p.add_argument("experiment", choices=(*EXPERIMENTS, "all"))
    p.add_argument("--seeds", type=int, default=None,
                   help="run seeds of bracing and lifting (default: bracing 10, lifting 5; "
                   "without --seeds/--quick: what --out recorded for each experiment)")
    p.add_argument("--quick", action="store_true", help="a tiny variant of every experiment (smoke test)")
    p.add_argument("--lifting-interleave", type=int, default=None, metavar="K",
                   help="the lifting runs' (and contexts') learner option: an offline search of the local "
                   "critic's argmin every K-th update (daemon --interleave-every; default 0: the paper's "
                   "Algorithm 1; without it: what --out recorded)")
    p.add_argument("--out", type=output_dir, default="reproduce-results",
                   help="output directory (default ./reproduce-results)")
    p.add_argument("--pairs", type=int, default=None,
                   help=f"simulator/agent pairs started here and run in parallel (default 1; one core each; at most "
                   f"{PAIRS_PER_CORE} a core this process may use unless --oversubscribe)")
    p.add_argument("--oversubscribe", action="store_true",
                   help=f"start --pairs N even above {PAIRS_PER_CORE} pairs a core this process may use")
    add_agents_arguments(p)
    p.set_defaults(func=_main)
