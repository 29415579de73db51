"""Typed, frozen daemon configuration: defaults < TOML file < command-line flags.

A :class:`DaemonConfig` is valid once it exists (``__post_init__`` checks every field), so
the service never re-validates. Two groups of fields:

* *learner* fields (:data:`LEARNER_FIELDS`) define a learning run and are stored with it:
  task, theta0, sigma, eta, epsilon, lr_range, kappa (the initial one), weights, seed
  (plus the episode budget). A resumed run takes them from the store (``service.open_run``).
* *operational* fields (robot, prefix, zenoh endpoints, db path, timeouts, retry policy,
  resume choice, linger) belong to one invocation of the daemon.

TOML file (``--config FILE``): a flat table whose keys are the field names below, plus an
optional ``[weights]`` table::

    robot = "ubot1"
    task = "bracing"
    fleet = ["ubot2", "lab$*"]         # more agents serving this run's episodes
    batch = 2                          # perturbations per update (default 1)
    interleave_every = 5               # offline search every 5th update (default 0: off)
    kappa = 2.0
    episodes = 45
    zenoh = ["tls/192.0.2.10:7447"]
    zenoh_config = "/etc/ersac-hil/daemon.json5"
    db = "ersac.db"
    [weights]
    damage = 10.0
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from typing import TYPE_CHECKING, Annotated, Any, Literal

import msgspec
from msgspec import Meta
from msgspec.structs import force_setattr

from protocol.zenoh import DEFAULT_PREFIX, KAPPA_MAX, KAPPA_MIN, InvalidField, KeySpace, get_task
from protocol.zenoh.codec import ID_PATTERN
from protocol.zenoh.fields import Finite, Name, NonNegative, Positive, Record, converting
from protocol.tomlfile import read_toml
from protocol.zenoh.tasks import TaskName

if TYPE_CHECKING:
    from ersac_hil.zenoh_session import ZenohOptions

__all__ = [
    "ConfigError",
    "DaemonConfig",
    "LEARNER_FIELDS",
    "TASK_DEFAULTS",
    "TaskDefaults",
    "check_source",
    "task_defaults",
    "load_toml",
    "merge",
]


class ConfigError(ValueError):
    """A configuration value, file or combination the daemon refuses."""


#: Fields that define a learning run (stored with it; a resumed run keeps the stored ones).
LEARNER_FIELDS: tuple[str, ...] = (
    "task", "theta0", "sigma", "eta", "epsilon", "lr_range", "kappa", "weights", "seed", "batch",
    "interleave_every", "learner",
)
#: The value of a learner field a run stored before the field existed.
LEGACY_SETTINGS: dict[str, Any] = {"batch": 1, "interleave_every": 0, "learner": "guarded"}
#: One key chunk naming robots: a name or a pattern with ``*`` / ``$*`` (e.g. ``ubot$*``).
FLEET_PATTERN = re.compile(r"\*|(?:[A-Za-z0-9_.\-]|\$\*){1,64}")


def check_source(source: str, prefix: str = DEFAULT_PREFIX) -> str:
    """``source`` if it is a robot name or a one-chunk key expression of names under ``prefix``
    (``ubot2``, ``*``, ``ubot$*``), else ``ValueError`` saying so."""
    import zenoh
    try:
        if not FLEET_PATTERN.fullmatch(source):
            raise ValueError
        zenoh.KeyExpr(f"{prefix}/{source}/agent/alive")
    except (ValueError, zenoh.ZError):
        raise ValueError(f"{source!r} is neither a robot name nor a one-chunk key expression of names "
                         "(e.g. ubot2, *, ubot$*)") from None
    return source


class TaskDefaults(msgspec.Struct, frozen=True):
    """The learner settings of a new run of one task unless configured (shapes ``(dim,)``)."""

    theta0: tuple[float, ...]
    sigma: tuple[float, ...]
    eta: float
    epsilon: float
    lr_range: tuple[float, float]
    episodes: int


#: The paper's settings (Kuindersma, Grupen & Barto 2012, Sections 5.1-5.2) per task.
#: bracing: eta 0.7, sigma 0.05, epsilon = 4 sigma = 0.2, eta / r~ in [0.01, 0.5], 45 episodes,
#: from a low-stiffness policy. lifting: eta 0.5, sigma 0.075 (every parameter: rad for the
#: waypoints, s for the durations), epsilon = 3.5 sigma, eta / r~ in [0.01, 0.5], 30 episodes,
#: from a hand-selected smooth, short motion to the goal that succeeds only part of the time:
#: waypoints on the straight line in joint space from the start pose (0, 0.95) to the goal pose
#: (2.657, 0.3), 0.4 s per segment (docs/daemon.md: its measured success rate).
TASK_DEFAULTS: dict[str, TaskDefaults] = {
    "bracing": TaskDefaults(theta0=(0.2,), sigma=(0.05,), eta=0.7, epsilon=0.2, lr_range=(0.01, 0.5),
                            episodes=45),
    "lifting": TaskDefaults(theta0=(0.886, 0.733, 1.771, 0.517, 0.72, 0.72, 0.72), sigma=(0.075,) * 7,
                            eta=0.5, epsilon=3.5 * 0.075, lr_range=(0.01, 0.5), episodes=30),
}
#: Sentinel values of ``resume``.
RESUME_LATEST, RESUME_NEW = "latest", "new"


def task_defaults(task: str) -> TaskDefaults:
    """The default learner settings of ``task`` (``InvalidField`` if it has none)."""
    spec = get_task(task)
    if spec.name not in TASK_DEFAULTS:
        raise InvalidField("task", f"no default settings for task {task!r}")
    return TASK_DEFAULTS[spec.name]


Kappa = Annotated[float, Meta(ge=KAPPA_MIN, le=KAPPA_MAX)]
#: What a simulator prior is used for (``DaemonConfig.prior_use``).
PriorUse = Literal["start", "critic"]
#: Settings that were renamed: the old key -> the new spelling (refused with this hint).
RENAMED: dict[str, str] = {"prior_critic": 'prior_use = "critic"'}
Seconds = Annotated[float, Meta(gt=0.0, le=86_400.0)]


class DaemonConfig(Record, frozen=True, kw_only=True):
    """Everything the learner daemon needs. Shapes: ``dim`` = the task's parameter count.

    Field types carry their constraints (msgspec); a config that exists is valid, so the
    service never re-validates. Invalid values raise :class:`ConfigError` naming the field.

    Attributes:
        robot: robot name (one Zenoh key chunk); keys live under ``<prefix>/<robot>``. It
            names the run (store) and the control plane (``<prefix>/<robot>/learner/...``),
            and its agent serves the run's episodes.
        fleet: more robots whose agents serve the run's episodes, each a name or a one-chunk
            key expression of names (``*``, ``ubot$*``); every agent present is used, work
            goes to whichever is free (``--robot A --robot B``: robot A, fleet (B,)).
        batch: perturbations per update, evaluated in parallel on the fleet and combined as
            the average of their eq. 10 terms (1: the paper's Algorithm 1).
        interleave_every: interleaved offline/online search (docs/learner.md): after every
            k-th update theta may move to the local argmin of F~ on that update's critic;
            0: off, the paper's Algorithm 1; ``None``: the learner preset's.
        prior: a simulator prior for a new run (``ersac-hil daemon --prior PATH``: a landscape,
            a ``reproduce`` directory or a store; ``daemon/prior.py``): the run starts from the
            simulated optimum for its kappa (unless ``theta0`` is given) and drops the prior
            when the robot's warm-up episodes disagree with it (docs/learner.md); read when the
            run is created, stored with it, ignored on resume.
        prior_use: what the ``prior`` gives the run (``--prior-use``): ``start`` (default) the
            start and its check after the warm-up; ``critic`` also, with a landscape prior of a
            1-D task, the critic's prior mean while the prior is kept (the residual model,
            docs/learner.md "Simulator prior"; not the default: measured worse than the start
            alone where the simulated optimum is wrong by 0.2). Given without a ``prior``: refused.
        learner: named learner settings (``ersac_hil.learner.presets``: ``paper``, ``guarded``,
            ``select``); ``None``: the task's default (bracing ``select``, lifting ``guarded``).
        prefix: key prefix (default ``ersac``).
        task: ``bracing`` or ``lifting`` (``protocol.zenoh.TASKS``).
        kappa: initial risk sensitivity in ``[KAPPA_MIN, KAPPA_MAX]``.
        episodes: successful ("ok") episodes after which the run is finished; ``None``: the
            task's default (:data:`TASK_DEFAULTS`) for a new run, the stored budget for a
            resumed one.
        seed: run seed (learner RNG and scenario seeds derive from it); ``None`` draws one
            when the run is created (it is stored).
        theta0: initial policy mean, ``(dim,)`` within the task bounds.
        sigma: exploration std per parameter, ``(dim,)``, > 0.
        eta: learning rate numerator of the update (``eta / r~`` is clipped to ``lr_range``).
        epsilon: radius of the critic's neighbourhood ball (in theta units).
        lr_range: ``(lo, hi)`` clip of ``eta / r~``, ``0 < lo <= hi``.
            Each of theta0, sigma, eta, epsilon, lr_range: ``None`` takes the task's paper
            setting (:data:`TASK_DEFAULTS`).
        weights: complete cost-term weights (the task's term names), >= 0.
        zenoh: Zenoh endpoints to connect to as a client (default: the ``zenoh_config``
            file's, else ``tcp/127.0.0.1:7447``); off loopback only ``tls/`` unless insecure.
        zenoh_config: a Zenoh json5 config file (TLS certificates...), ``--zenoh-config``.
        insecure: allow plain endpoints off loopback (``--insecure``).
        db: SQLite store path.
        episode_timeout_s: how long one ``episode/run`` query may take.
        max_attempts: attempts of one request (faults, timeouts, refusals) before the run
            is marked failed; waiting for an absent agent does not count.
        backoff_s: ``(initial, max)`` wait between attempts, doubled after each failure.
        agent_wait_s: give up (run stays resumable) after waiting this long for an absent
            agent; ``None`` waits forever.
        resume: ``"latest"`` (the latest unfinished run of this robot and task, else a new
            one), ``"new"`` or a run id.
        linger: keep serving the control plane after the run finished (until SIGTERM).
        explicit: names of the fields set by a file or a flag (not defaults); a resumed run
            refuses explicit learner fields that differ from its stored ones.
    """

    robot: str
    fleet: tuple[str, ...] = ()
    batch: Annotated[int, Meta(ge=1, le=64)] = 1
    interleave_every: Annotated[int, Meta(ge=0, le=1000)] | None = None
    learner: str | None = None
    prior: str | None = None
    prior_use: PriorUse = "start"
    task: TaskName = "bracing"
    kappa: Kappa = 0.0
    episodes: Annotated[int, Meta(ge=1, le=1_000_000)] | None = None
    seed: Annotated[int, Meta(ge=0, le=2**63 - 1)] | None = None
    theta0: tuple[Finite, ...] | None = None
    sigma: tuple[Positive, ...] | None = None
    eta: Positive | None = None
    epsilon: Positive | None = None
    lr_range: tuple[Positive, Positive] | None = None
    weights: dict[Name, NonNegative] | None = None
    prefix: str = DEFAULT_PREFIX
    zenoh: tuple[str, ...] = ()
    zenoh_config: str | None = None
    insecure: bool = False
    db: str = "ersac.db"
    episode_timeout_s: Seconds = 60.0
    max_attempts: Annotated[int, Meta(ge=1, le=1000)] = 5
    backoff_s: tuple[Positive, Positive] = (0.5, 10.0)
    agent_wait_s: Positive | None = None
    resume: str = RESUME_LATEST
    linger: bool = False
    explicit: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        try:
            super().__post_init__()
        except InvalidField as exc:
            if converting():
                raise
            raise ConfigError(str(exc)) from None

    def _check(self) -> None:
        set_ = lambda k, v: force_setattr(self, k, v)  # noqa: E731
        if "*" in self.robot:
            raise InvalidField("robot", f"{self.robot!r}: the (first) robot names the run and its control "
                                        "plane, so it is a plain name; patterns come after it "
                                        "(--robot ubot1 --robot 'ubot$*')")
        try:
            KeySpace(self.robot, self.prefix)
        except ValueError as exc:
            raise InvalidField("robot", str(exc)) from None
        for source in self.fleet:
            try:
                check_source(source, self.prefix)
            except ValueError as exc:
                raise InvalidField("fleet", str(exc)) from None
        spec = get_task(self.task)
        defaults = task_defaults(self.task)
        from ersac_hil.learner.presets import PRESETS, TASK_LEARNER
        learner = TASK_LEARNER.get(spec.name, "guarded") if self.learner is None else self.learner
        if learner not in PRESETS:
            raise InvalidField("learner", f"unknown learner {learner!r}; known: {', '.join(PRESETS)}")
        set_("learner", learner)
        if self.interleave_every is None:
            set_("interleave_every", PRESETS[learner].interleave_every)
        set_("theta0", spec.check_theta(defaults.theta0 if self.theta0 is None else self.theta0, "theta0"))
        sigma = defaults.sigma if self.sigma is None else self.sigma
        if len(sigma) != spec.dim:
            raise InvalidField("sigma", f"needs {spec.dim} values for this task, got {len(sigma)}")
        set_("sigma", sigma)
        set_("eta", defaults.eta if self.eta is None else self.eta)
        set_("epsilon", defaults.epsilon if self.epsilon is None else self.epsilon)
        lr = defaults.lr_range if self.lr_range is None else self.lr_range
        if not lr[0] <= lr[1]:
            raise InvalidField("lr_range", f"must satisfy 0 < lo <= hi, got {lr}")
        set_("lr_range", lr)
        weights = dict(spec.default_weights)
        if self.weights is not None:
            spec.check_names(self.weights, "weights", complete=False)
            weights.update(self.weights)
        set_("weights", {k: weights[k] for k in spec.term_names})
        if self.prior is None and "prior_use" in self.explicit:
            raise InvalidField("prior_use", f"{self.prior_use!r} needs a prior (--prior PATH)")
        if self.prior is not None:
            from .prior import PriorError, load_prior
            try:
                load_prior(self.prior, spec.name, self.kappa, self.weights)
            except PriorError as exc:
                raise InvalidField("prior", str(exc)) from None
        from ersac_hil.zenoh_session import ZenohConfigError, resolve_config
        try:
            resolve_config(self.zenoh_options)
        except ZenohConfigError as exc:
            raise InvalidField("zenoh", str(exc)) from None
        if not self.backoff_s[0] <= self.backoff_s[1]:
            raise InvalidField("backoff_s", f"must satisfy 0 < initial <= max, got {self.backoff_s}")
        if not (self.resume in (RESUME_LATEST, RESUME_NEW) or ID_PATTERN.fullmatch(self.resume)):
            raise InvalidField("resume", f"must be 'latest', 'new' or a run id, got {self.resume!r}")

    @property
    def episodes_or_default(self) -> int:
        return task_defaults(self.task).episodes if self.episodes is None else self.episodes

    @property
    def zenoh_options(self) -> ZenohOptions:
        """The session options (``ersac_hil.zenoh_session.resolve_config``)."""
        from ersac_hil.zenoh_session import ZenohOptions
        return ZenohOptions(self.zenoh, self.zenoh_config, self.insecure)

    @property
    def keys(self) -> KeySpace:
        """The robot's Zenoh key space."""
        return KeySpace(self.robot, self.prefix)

    @property
    def sources(self) -> tuple[str, ...]:
        """The robot names and patterns whose agents serve the run (robot first, no repeats)."""
        return tuple(dict.fromkeys((self.robot, *self.fleet)))

    def learner_settings(self) -> dict[str, Any]:
        """The learner fields as a JSON-ready dict (stored with a run)."""
        out = {name: getattr(self, name) for name in LEARNER_FIELDS}
        out["weights"] = dict(self.weights or {})
        for key in ("theta0", "sigma", "lr_range"):
            out[key] = list(out[key])
        out["episodes"] = self.episodes_or_default
        return out

    def with_learner_settings(self, stored: Mapping[str, Any]) -> DaemonConfig:
        """This config with the learner fields of a stored run (``episodes`` is left as is)."""
        changes = {k: stored[k] for k in LEARNER_FIELDS if k in stored}
        for key in ("theta0", "sigma", "lr_range"):
            if key in changes:
                changes[key] = tuple(changes[key])
        return type(self)(**{**msgspec.structs.asdict(self), **changes})

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of every field."""
        out = msgspec.structs.asdict(self)
        out["weights"] = dict(self.weights or {})
        out["explicit"] = sorted(self.explicit)
        return out


_FIELD_NAMES = set(DaemonConfig.__struct_fields__)


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML config file into field values (unknown keys are an error).

    Raises:
        ConfigError: unreadable file, invalid TOML, unknown key.
    """
    data = read_toml(path, ConfigError, "config file ")
    renamed = sorted(set(data) & set(RENAMED))
    if renamed:
        raise ConfigError(f"config file {path}: {renamed[0]} was renamed: use {RENAMED[renamed[0]]}")
    unknown = sorted(set(data) - (_FIELD_NAMES - {"explicit"}))
    if unknown:
        raise ConfigError(f"config file {path}: unknown keys {unknown}; known: {sorted(_FIELD_NAMES)}")
    out = dict(data)
    for key in ("theta0", "sigma", "lr_range", "backoff_s", "zenoh", "fleet"):
        if isinstance(out.get(key), list):
            out[key] = tuple(out[key])
    for key in ("zenoh", "fleet"):
        if isinstance(out.get(key), str):
            out[key] = (out[key],)
    return out


def merge(file_values: Mapping[str, Any], flag_values: Mapping[str, Any]) -> DaemonConfig:
    """Build the config: defaults, then the file's values, then every flag that is not ``None``.

    Weights merge per name (a flag ``--weight damage=20`` keeps the file's other weights).

    Raises:
        ConfigError: missing robot, invalid values, unknown keys.
    """
    values: dict[str, Any] = dict(file_values)
    flag_weights = dict(flag_values.get("weights") or {})
    for key, value in flag_values.items():
        if key == "weights" or value is None:
            continue
        if key not in _FIELD_NAMES:
            raise ConfigError(f"unknown setting {key!r}")
        values[key] = value
    if flag_weights:
        values["weights"] = {**dict(values.get("weights") or {}), **flag_weights}
    values["explicit"] = frozenset(k for k in values if k != "explicit")
    if "robot" not in values:
        raise ConfigError("the robot name is required (--robot NAME or robot = \"...\" in the config file)")
    try:
        return DaemonConfig(**values)
    except TypeError as exc:  # an unknown keyword
        raise ConfigError(str(exc)) from None

