"""``ersac-hil`` subcommands of the daemon package (picked up by ``ersac_hil.cli``).

Services: ``daemon`` (the learner), ``router`` (Zenoh router, loopback unless configured).
Every command that opens a Zenoh session takes ``--zenoh ENDPOINT``, ``--zenoh-config FILE``
and ``--insecure`` (``ersac_hil.zenoh_session.resolve_config``).
Clients (Zenoh client sessions): ``state``, ``kappa get|set``, ``weights get|set``,
``critic``, ``select``. Offline: ``report``.

Exit codes: 0 ok (also: the latest run is already finished, nothing to do), 1 request
refused / no answer, 2 invalid arguments or configuration,
3 run failed, 4 agent absent too long, 5 the store cannot be written (disk full, I/O error;
the run stops with nothing half-written and resumes once there is space), 128+N on signal N.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ersac_hil.cli_args import UsageError, add_prefix_argument, file_in_dir, output_dir, positive_float, tcp_port

__all__ = ["register"]


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers") from None


def _weight(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: {value!r} is not a number") from None


class _Renamed(argparse.Action):
    """A renamed flag: refused with the new spelling (argparse's usage error, exit 2)."""

    def __init__(self, *args: Any, new: str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        parser.error(f"{option_string} was renamed: use {self.new}")


def _fail(message: str, code: int = 2) -> int:
    print(f"ersac-hil: {message}", file=sys.stderr, flush=True)
    return code


# --------------------------------------------------------------------------- services
def _daemon(args: argparse.Namespace) -> int:
    from ersac_hil.lifecycle import serve

    from .config import ConfigError, load_toml, merge
    from .runs import RunFinished
    from .service import Daemon
    from .service import EXIT_STORE
    from .store import StoreError, StoreUnwritable
    from ersac_hil.zenoh_session import ZenohSessionError

    flags: dict[str, Any] = {
        "robot": args.robot[0] if args.robot else None,
        "fleet": tuple(args.robot[1:]) if args.robot and len(args.robot) > 1 else None,
        "batch": args.batch, "interleave_every": args.interleave_every, "learner": args.learner, "prior": args.prior,
        "prior_use": args.prior_use, "prefix": args.prefix, "task": args.task, "kappa": args.kappa,
        "episodes": args.episodes, "seed": args.seed, "theta0": args.theta0, "sigma": args.sigma,
        "eta": args.eta, "epsilon": args.epsilon, "lr_range": args.lr_range,
        "zenoh": tuple(args.zenoh) if args.zenoh else None, "zenoh_config": args.zenoh_config,
        "insecure": True if args.insecure else None,
        "db": Path(args.db) if args.db else None, "episode_timeout_s": args.episode_timeout,
        "max_attempts": args.max_attempts, "backoff_s": args.backoff, "agent_wait_s": args.agent_wait,
        "resume": "new" if args.new else args.resume, "linger": True if args.linger else None,
        "weights": dict(args.weight) if args.weight else None,
    }
    try:
        config = merge(load_toml(args.config) if args.config else {}, flags)
        daemon = Daemon(config)
        code = serve(daemon, until=daemon.finished)
    except RunFinished as exc:  # a supervisor's restart after the end: not an error
        print(f"ersac-hil daemon: {exc}", flush=True)
        return 0
    except StoreUnwritable as exc:  # at start: the new run or the resumed run's first write
        return _fail(str(exc), EXIT_STORE)
    except (ConfigError, StoreError) as exc:
        return _fail(str(exc))
    except ZenohSessionError as exc:
        return _fail(str(exc), 1)
    return code or daemon.exit_code


class _RouterService:
    def __init__(self, args: argparse.Namespace) -> None:
        from ersac_hil.zenoh_session import EmbeddedRouter, resolve_config, zenoh_options
        options = zenoh_options(args)
        if options.endpoints or options.config_file:
            self.router = EmbeddedRouter(config=resolve_config(options, mode="router"),
                                         insecure=options.insecure)
        else:
            self.router = EmbeddedRouter(port=args.port or None)

    def start(self) -> None:
        self.router.start()
        print(f"Zenoh router: {self.router.endpoint}", flush=True)

    def stop(self) -> None:
        self.router.close()
        print("Zenoh router stopped", flush=True)


def _router(args: argparse.Namespace) -> int:
    from ersac_hil.lifecycle import serve
    from ersac_hil.zenoh_session import ZenohConfigError, ZenohSessionError
    try:
        return serve(_RouterService(args))
    except ZenohConfigError as exc:
        return _fail(str(exc))
    except ZenohSessionError as exc:
        return _fail(str(exc), 1)


# --------------------------------------------------------------------------- clients
def _client_call(args: argparse.Namespace, action, render=None, needs: str = "state") -> int:  # noqa: ANN001
    """Run ``action(client)``; print ``render(reply)`` (default: human text, or the reply's
    JSON with ``--json``). Maps failures to exit codes 1 (refused / no answer) and 2 (also:
    the identity's role may not do ``needs``, a key of ``clients.ACTIONS``: said before any
    session is opened)."""
    from protocol.zenoh import KeySpace, PayloadError
    from ersac_hil.zenoh_session import ZenohConfigError, ZenohSessionError, zenoh_options

    from .clients import ClientError, LearnerClient, NotPermitted, RequestRefused, check_permitted, identity_role

    try:
        keys = KeySpace(args.robot, args.prefix)
        options = zenoh_options(args)
        check_permitted(identity_role(options), needs)
    except NotPermitted as exc:
        return _fail(str(exc))
    except (ZenohConfigError, ValueError) as exc:
        return _fail(str(exc))
    try:
        with LearnerClient(keys, options, args.timeout) as client:
            reply = action(client)
    except (PayloadError, ZenohConfigError, ValueError) as exc:
        return _fail(str(exc))
    except RequestRefused as exc:
        return _fail(f"refused ({exc.error.code}): {exc.error.reason}", 1)
    except (ClientError, ZenohSessionError) as exc:
        return _fail(str(exc), 1)
    if args.json:
        print(reply.to_json().decode(), flush=True)
    else:
        print((render or _human)(reply), flush=True)
    return 0


def _human(reply: Any) -> str:
    kind = reply.TYPE
    if kind == "learner_state":
        lines = [f"run       {reply.run_id}", f"task      {reply.task}", f"status    {reply.status}",
                 f"episodes  {reply.episode_count}", f"theta     {list(reply.theta)}",
                 f"sigma     {list(reply.sigma)}", f"kappa     {reply.kappa:g}",
                 f"weights   {dict(reply.weights)}"]
        return "\n".join(lines)
    if kind == "critic_reply":
        rows = [f"{'theta':>24}  {'J~':>10}  {'r~':>10}  {'F~':>10}   (kappa {reply.kappa:g})"]
        rows += [f"{','.join(f'{x:.4f}' for x in p.theta):>24}  {p.J:10.4f}  {p.r:10.4f}  {p.F:10.4f}"
                 for p in reply.points]
        return "\n".join(rows)
    if kind == "select_reply":
        return (f"selected theta {list(reply.theta)}\nJ~ {reply.J:.4f}  r~ {reply.r:.4f}  "
                f"F~ {reply.F:.4f}  (kappa {reply.kappa:g})\nweights {dict(reply.weights)}\n"
                f"adopted {reply.adopted}")
    return reply.to_json().decode()


def _state(args: argparse.Namespace) -> int:
    code = _client_call(args, lambda c: c.state())
    if not args.json:  # the agent's phase too: waiting for go, stopped by an e-stop...
        from ersac_hil.agent.operator import print_agent_state
        print_agent_state(args)
    return code


def _payload(build):  # noqa: ANN001, ANN202
    """Build a request payload from the command line: its own validation is the usage check,
    made before any session is opened."""
    from protocol.zenoh import PayloadError
    try:
        return build()
    except PayloadError as exc:
        raise UsageError(str(exc)) from None


def _check_kappa(args: argparse.Namespace) -> None:
    from protocol.zenoh import KappaCommand
    if args.action == "get" and args.value is not None:
        raise UsageError("kappa get takes no value")
    if args.action == "set":
        if args.value is None:
            raise UsageError("kappa set needs a VALUE")
        _payload(lambda: KappaCommand(args.value))


def _kappa(args: argparse.Namespace) -> int:
    if args.action == "get":
        return _client_call(args, lambda c: c.state(), lambda s: f"{s.kappa:g}")
    return _client_call(args, lambda c: c.set_kappa(args.value), needs="kappa")


def _check_weights(args: argparse.Namespace) -> None:
    from protocol.zenoh import TASKS, WeightsCommand
    if args.action == "get" and args.weight:
        raise UsageError("weights get takes no values")
    if args.action == "set":
        if not args.weight:
            raise UsageError("weights set needs NAME=VALUE ...")
        terms = sorted({t for spec in TASKS.values() for t in spec.term_names})
        unknown = [name for name, _ in args.weight if name not in terms]
        if unknown:  # which task's terms apply only the learner knows; these are no task's
            raise UsageError(f"{', '.join(unknown)}: not a cost term of any task (known: {', '.join(terms)})")
        _payload(lambda: WeightsCommand(dict(args.weight)))


def _weights(args: argparse.Namespace) -> int:
    if args.action == "get":
        return _client_call(args, lambda c: c.state(), lambda s: json.dumps(dict(s.weights)))
    return _client_call(args, lambda c: c.set_weights(dict(args.weight)), needs="weights")


def _check_critic(args: argparse.Namespace) -> None:
    from protocol.zenoh import CriticQuery
    if (args.grid is None) == (not args.theta):
        raise UsageError("give --theta (repeatable) or --grid N")
    args.query = _payload(lambda: CriticQuery(tuple(args.theta or ()), args.grid, args.kappa))


def _critic(args: argparse.Namespace) -> int:
    return _client_call(args, lambda c: c.critic(args.query), needs="critic")


def _check_select(args: argparse.Namespace) -> None:
    from protocol.zenoh import SelectQuery
    args.query = _payload(lambda: SelectQuery(args.kappa, dict(args.weight) if args.weight else None,
                                              args.adopt))


def _select(args: argparse.Namespace) -> int:
    return _client_call(args, lambda c: c.select(args.query), needs="select")


# --------------------------------------------------------------------------- report
def _check_report(args: argparse.Namespace) -> None:
    if not Path(args.db).is_file():
        raise UsageError(f"no store at {args.db}")
    if args.series is not None and not Path(args.series).is_dir():
        raise UsageError(f"--series: no directory {args.series}")
    if args.mcap is not None and not Path(args.mcap).resolve().parent.is_dir():
        raise UsageError(f"--mcap: no directory for {args.mcap}")
    if args.mcap_dir is not None and (args.mcap is None or not Path(args.mcap_dir).is_dir()):
        raise UsageError(f"--mcap-dir: no directory {args.mcap_dir}" if args.mcap is not None
                         else "--mcap-dir needs --mcap FILE")


def _report(args: argparse.Namespace) -> int:
    from .report import write_report
    from .store import Store, StoreError
    try:
        run_id = args.run_id
        if run_id == "latest":
            with Store(args.db, readonly=True) as store:
                runs = store.runs()
            if not runs:
                return _fail(f"no run in {args.db}")
            run_id = runs[-1].run_id
        if args.mcap is not None:
            from ersac_hil.ros2.export import export_run
            done = export_run(args.db, run_id, args.mcap, args.mcap_dir)
            print(f"run {run_id} in {done.path.resolve()}: {done.attempts} episodes, {done.updates} updates, "
                  f"{done.episode_files} episode files" + (f" ({len(done.missing)} missing: "
                  f"{', '.join(done.missing)})" if done.missing else ""), flush=True)
            return 0
        summary = write_report(args.db, run_id, args.out, series=args.series)
    except StoreError as exc:
        return _fail(str(exc))
    print(f"report of run {summary['run_id']} in {Path(args.out).resolve()}: "
          f"{', '.join(summary['files'])}", flush=True)
    return 0


# --------------------------------------------------------------------------- parsers
def _client_options(p: argparse.ArgumentParser) -> None:
    from ersac_hil.zenoh_session import add_zenoh_arguments
    p.add_argument("--robot", default="ubot1", help="robot name (default ubot1)")
    add_prefix_argument(p)
    add_zenoh_arguments(p)
    p.add_argument("--timeout", type=positive_float, default=10.0, help="seconds per request (default 10)")
    p.add_argument("--json", action="store_true", help="print the reply payload as JSON")


def register(sub: argparse._SubParsersAction) -> None:
    """Add this package's subcommands to the ``ersac-hil`` parser."""
    from ersac_hil.daemon.config import TASK_DEFAULTS
    from ersac_hil.zenoh_session import add_zenoh_arguments
    from protocol.zenoh.keys import DEFAULT_PREFIX
    paper = ", ".join(f"{task} {d.episodes}" for task, d in TASK_DEFAULTS.items())
    p = sub.add_parser("daemon", help="the learner daemon (ERSAC against the agent's episode/run)",
                       description="Learn with ERSAC by asking the robot-side agent to run episodes. "
                                   "Flags override the --config TOML file.")
    p.add_argument("--config", metavar="FILE", help="TOML config file (keys = long flag names with _)")
    p.add_argument("--robot", action="append",
                   help="robot name (required here or in the file); repeat for a fleet: the first "
                        "names the run and its control plane, every one (a name or a one-chunk key "
                        "expression such as 'ubot$*') serves its episodes")
    p.add_argument("--batch", type=int,
                   help="perturbations per update, run in parallel on the fleet (default 1: the paper's)")
    p.add_argument("--interleave-every", dest="interleave_every", type=int, metavar="K",
                   help="interleaved offline search: after every K-th update move to the local argmin "
                        "of F~ when the critic is confident of the gain (default: the --learner's, "
                        "select 1, paper and guarded 0: off; docs/learner.md)")
    p.add_argument("--learner", help="named learner settings: paper (Algorithm 1), guarded (+ move guard), "
                                      "select (+ interleaved search, final offline selection), trust (select with a "
                                      "trust-region step along F~); default: "
                                      "bracing select, lifting guarded (docs/learner.md)")
    p.add_argument("--prior", metavar="PATH",
                   help="simulator prior of a new run: a landscape JSON, a reproduce directory or a store "
                        "of simulated episodes of the task; start from its optimum for kappa, drop it if "
                        "the robot's warm-up episodes disagree (docs/learner.md)")
    p.add_argument("--prior-use", dest="prior_use", choices=("start", "critic"),
                   help="what --prior gives the run: start (default) the start and its check; critic also, "
                        "with a landscape, the critic's prior mean (residual model; docs/learner.md)")
    p.add_argument("--prior-critic", action=_Renamed, nargs=0, help=argparse.SUPPRESS, new="--prior-use critic")
    p.add_argument("--prefix", help=f"key prefix (default {DEFAULT_PREFIX})")
    p.add_argument("--task", choices=("bracing", "lifting"), help="task (default bracing)")
    p.add_argument("--kappa", type=float, help="risk sensitivity (default 0; > 0 risk averse)")
    p.add_argument("--episodes", type=int, help=f"ok episodes in the run (default: the paper's, {paper})")
    p.add_argument("--seed", type=int, help="run seed (default: random, stored)")
    p.add_argument("--theta0", type=_floats, help="initial policy mean, comma-separated (default: the task's, docs/daemon.md)")
    p.add_argument("--sigma", type=_floats, help="exploration std per parameter, comma-separated (default: bracing 0.05, lifting 0.075)")
    p.add_argument("--eta", type=float, help="learning rate (default: bracing 0.7, lifting 0.5)")
    p.add_argument("--epsilon", type=float, help="critic neighbourhood radius (default: bracing 0.2, lifting 0.2625)")
    p.add_argument("--lr-range", dest="lr_range", type=_floats, help="clip of eta/r~ (default 0.01,0.5)")
    p.add_argument("--weight", action="append", type=_weight, metavar="NAME=VALUE",
                   help="cost-term weight (repeatable; default: the task's)")
    add_zenoh_arguments(p)
    p.add_argument("--db", type=file_in_dir, help="SQLite store (default ersac.db)")
    p.add_argument("--episode-timeout", dest="episode_timeout", type=float,
                   help="seconds one episode may take (default 60)")
    p.add_argument("--max-attempts", dest="max_attempts", type=int,
                   help="failed attempts of one request before the run fails (default 5)")
    p.add_argument("--backoff", type=_floats, metavar="INITIAL,MAX", help="retry backoff (default 0.5,10)")
    p.add_argument("--agent-wait", dest="agent_wait", type=float,
                   help="give up after waiting this long for an absent agent (default: forever)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--resume", metavar="RUN_ID",
                       help="resume this run (default: the latest unfinished run of robot+task)")
    group.add_argument("--new", action="store_true", help="start a new run")
    p.add_argument("--linger", action="store_true", help="keep serving the control plane when done")
    p.set_defaults(func=_daemon)

    if "router" not in sub.choices:
        p = sub.add_parser("router", help="Zenoh router (loopback by default; TLS + access control "
                                          "with --zenoh-config)")
        p.add_argument("--port", type=tcp_port, default=7447,
                       help="listen on tcp/127.0.0.1:PORT (default 7447; 0 = a free one) "
                            "unless --zenoh or --zenoh-config say where")
        add_zenoh_arguments(p, listens=True)
        p.set_defaults(func=_router)

    p = sub.add_parser("state", help="the learner's state (theta, kappa, weights, episodes)")
    _client_options(p)
    p.set_defaults(func=_state)

    p = sub.add_parser("kappa", help="get or set the learner's risk sensitivity")
    p.add_argument("action", choices=("get", "set"))
    p.add_argument("value", nargs="?", type=float)
    _client_options(p)
    p.set_defaults(func=_kappa, validate=_check_kappa)

    p = sub.add_parser("weights", help="get or set the cost-term weights (re-costs every episode)")
    p.add_argument("action", choices=("get", "set"))
    p.add_argument("weight", nargs="*", type=_weight, metavar="NAME=VALUE")
    _client_options(p)
    p.set_defaults(func=_weights, validate=_check_weights)

    p = sub.add_parser("critic", help="critic J~, r~, F~ at points or on a grid")
    p.add_argument("--theta", action="append", type=_floats, help="a point, comma-separated; repeatable")
    p.add_argument("--grid", type=int, help="N points per dimension over the task box")
    p.add_argument("--kappa", type=float, help="kappa for F~ (default: the learner's)")
    _client_options(p)
    p.set_defaults(func=_critic, validate=_check_critic)

    p = sub.add_parser("select", help="offline policy selection: minimise F~ = J~ + kappa r~")
    p.add_argument("--kappa", type=float, required=True)
    p.add_argument("--weight", action="append", type=_weight, metavar="NAME=VALUE",
                   help="cost-term weight for this selection (repeatable)")
    p.add_argument("--adopt", action="store_true", help="make the selected theta the policy mean")
    _client_options(p)
    p.set_defaults(func=_select, validate=_check_select)

    p = sub.add_parser("report", help="plots and summary.json of a run")
    p.add_argument("run_id", help="run id, or 'latest'")
    p.add_argument("--db", default="ersac.db", help="SQLite store (default ersac.db)")
    p.add_argument("--out", type=output_dir, default="report", help="output directory (default ./report)")
    p.add_argument("--series", metavar="DIR",
                   help="the agent's time series files (agent --record-series DIR): draws episode.png")
    p.add_argument("--mcap", metavar="FILE",
                   help="instead of plots: the run's episodes and learner updates as one MCAP file")
    p.add_argument("--mcap-dir", dest="mcap_dir", metavar="DIR",
                   help="the agent's MCAP episodes (agent --record DIR) to copy into --mcap")
    p.set_defaults(func=_report, validate=_check_report)
