"""Runs: open a new run or resume one, rebuild the learner from the store, derived seeds and ids.

Resume rules (:func:`open_run`): ``resume="latest"`` takes the latest ``running`` run of the
robot and task (else a new run) - unless the latest run of the robot and task is
``finished``: then there is nothing to do (:class:`RunFinished`; the CLI says so and exits 0,
so a supervisor restarting the daemon never repeats a finished run); ``"new"`` always
starts one, a run id picks that run. A
resumed run keeps its stored learner settings; explicitly given learner settings that differ
are refused, so a changed command line never silently continues an old run.

Rebuild (:func:`rebuild_engine`): the learner exactly as it was after the last committed
update (see ``engine.Engine.restore``); together with the derived scenario seeds
(:func:`scenario_seed`) a resumed daemon sends exactly the requests an uninterrupted one would.
"""
from __future__ import annotations

import dataclasses
import secrets
import time
from pathlib import Path

import numpy as np

from protocol.zenoh import get_task

from .config import LEARNER_FIELDS, LEGACY_SETTINGS, RESUME_LATEST, RESUME_NEW, ConfigError, DaemonConfig
from .engine import Engine
from .store import RunNotFound, RunRecord, Store

__all__ = ["RunFinished", "scenario_seed", "episode_id", "new_run_id", "plan_run", "check_store", "open_run",
           "rebuild_engine"]


class RunFinished(Exception):
    """``resume="latest"`` and the latest run of the robot and task is finished."""

    def __init__(self, run: RunRecord) -> None:
        super().__init__(f"run {run.run_id} of {run.robot}/{run.task} is already finished; nothing "
                         "to do (--new starts another run, --resume RUN_ID continues a given one)")
        self.run = run


def scenario_seed(run_seed: int, idx: int) -> int:
    """The scenario seed of learner episode ``idx`` (uint32), a pure function of both."""
    return int(np.random.SeedSequence([run_seed, 1, idx]).generate_state(1, np.uint32)[0])


def episode_id(run_id: str, idx: int, attempt: int) -> str:
    """``<run_id>.<idx:05d>.<attempt>``: unique per attempt."""
    return f"{run_id}.{idx:05d}.{attempt}"


def new_run_id() -> str:
    return time.strftime("%Y%m%dT%H%M%S") + "-" + secrets.token_hex(3)


def plan_run(store: Store, config: DaemonConfig) -> RunRecord | None:
    """The run ``config`` would resume in ``store`` (``None``: a new one), decided by reading
    only, so :func:`check_store` can refuse before anything is written.

    Raises:
        RunFinished: ``resume="latest"`` and the latest matching run is finished.
        ConfigError: a store of another robot or task, an unknown run id, a run of another
            robot/task, conflicting learner settings.
    """
    runs = store.runs()
    if runs and not any((r.robot, r.task) == (config.robot, config.task) for r in runs):
        held = ", ".join(sorted({f"{r.task} on {r.robot}" for r in runs}))
        raise ConfigError(f"{store.path} is a store of {held}, not of {config.task} on {config.robot}: "
                          "give another --db")
    run: RunRecord | None = None
    if config.resume == RESUME_LATEST:
        latest = store.latest_run(config.robot, config.task)
        if latest is not None and latest.status == "finished":
            raise RunFinished(latest)
        run = store.latest_unfinished(config.robot, config.task)
    elif config.resume != RESUME_NEW:
        try:
            run = store.run(config.resume)
        except RunNotFound as exc:
            raise ConfigError(str(exc)) from None
        if (run.robot, run.task) != (config.robot, config.task):
            raise ConfigError(f"run {run.run_id} is {run.task!r} on {run.robot!r}, not "
                              f"{config.task!r} on {config.robot!r}")
    if run is not None:
        stored = {**LEGACY_SETTINGS, **run.settings}
        given = config.learner_settings()
        conflicts = [k for k in LEARNER_FIELDS if k in config.explicit and given[k] != stored.get(k)]
        if conflicts:
            detail = ", ".join(f"{k}={stored.get(k)!r} (given {given[k]!r})" for k in conflicts)
            raise ConfigError(
                f"run {run.run_id} was started with {detail}; pass --new for a new run "
                "(kappa and weights can be changed at run time over the control plane)")
    return run


def check_store(config: DaemonConfig) -> None:
    """Refuse (as :func:`plan_run` would) what the daemon cannot run on ``config.db``, before
    any session is opened: the store is opened read-only and nothing is created or changed
    (a missing store is fine: it is created once the daemon has its session).

    Raises:
        StoreError: the file is not an ersac-hil store (or of a schema this code cannot open).
        ConfigError, RunFinished: see :func:`plan_run`.
    """
    path = Path(config.db)
    if not path.exists():
        if config.resume not in (RESUME_NEW, RESUME_LATEST):
            raise ConfigError(f"no run {config.resume!r}: no store at {path}")
        return
    with Store(path, readonly=True) as store:
        plan_run(store, config)


def open_run(store: Store, config: DaemonConfig) -> tuple[RunRecord, DaemonConfig, bool]:
    """Open the run ``config.resume`` asks for: ``(run, effective config, resumed)``.

    A resumed run keeps its stored learner settings; explicitly given learner settings that
    differ are refused (``ConfigError``), so a changed command line never silently continues
    an old run. ``episodes`` may be changed on resume (a new total budget). A store holds the
    runs of one robot and task: a store with runs of none of ``config``'s is refused.

    Raises:
        RunFinished: ``resume="latest"`` and the latest matching run is finished.
        ConfigError: a store of another robot or task, an unknown run id, another
            robot/task, conflicting learner settings.
    """
    run = plan_run(store, config)
    if run is None:
        seed = config.seed if config.seed is not None else secrets.randbits(62)
        settings = {**config.learner_settings(), "seed": seed}
        settings["episodes"] = config.episodes_or_default
        if config.prior is not None:
            from .prior import load_prior
            prior = load_prior(config.prior, config.task, config.kappa, config.weights)
            if config.prior_use != "critic":  # the landscape is what makes it the critic's prior
                prior = dataclasses.replace(prior, landscape=None)
            settings["prior"] = prior.to_dict()
            if "theta0" not in config.explicit:
                settings["theta0"] = list(get_task(config.task).check_theta(prior.theta, "prior theta"))
        run = store.create_run(new_run_id(), config.robot, config.task, seed, settings)
        return run, config.with_learner_settings(run.settings), False
    stored = {**LEGACY_SETTINGS, **run.settings}
    effective = config.with_learner_settings(stored)
    if config.episodes is not None and config.episodes != stored.get("episodes"):
        stored["episodes"] = config.episodes
    if run.status != "running" or stored != run.settings:
        store.set_run_status(run.run_id, "running", settings=stored)
        run = store.run(run.run_id)
    return run, effective, True


def rebuild_engine(store: Store, run: RunRecord) -> Engine:
    """The learner exactly as it was after the run's last committed update.

    Re-adds every ok episode that fed an update (executed theta, cost terms; the ok episodes
    of an incomplete batch are told with their batch), applies the latest kappa and
    weights, restores theta (the last update's, or a selection adopted after it) and the
    learner's state (RNG...) stored with the last update.
    """
    s = run.settings
    weights_change = store.latest_change(run.run_id, "weights")
    kappa_change = store.latest_change(run.run_id, "kappa")
    theta_change = store.latest_change(run.run_id, "theta")
    last = store.last_update(run.run_id)
    episodes = [e for e in store.ok_episodes(run.run_id) if e.update_idx is not None]
    n = 0 if last is None else last.idx + 1
    if any(e.idx != i for i, e in enumerate(episodes)) or {e.update_idx for e in episodes} != set(range(n)) \
            or [e.update_idx for e in episodes] != sorted(e.update_idx for e in episodes):
        raise RuntimeError(f"run {run.run_id}: ok episodes {[(e.idx, e.update_idx) for e in episodes]} "
                           f"do not match {n} updates")
    theta = tuple(s["theta0"]) if last is None else last.theta_after
    if theta_change is not None and theta_change.n_updates >= n:
        theta = tuple(theta_change.value)
    engine = Engine.restore(
        run.task, s,
        observations=[(e.theta, e.cost_terms) for e in episodes],
        kappa=float(kappa_change.value) if kappa_change else float(s["kappa"]),
        weights=dict(weights_change.value) if weights_change else dict(s["weights"]),
        theta=theta,
        state=None if last is None else dict(last.state),
    )
    if any(c.source.startswith("prior rejected") for c in store.changes(run.run_id, "theta")):
        engine.drop_critic_prior()  # rejected after the state of the last update was stored
    return engine
