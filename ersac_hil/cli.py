"""``ersac-hil``: one console script, one subcommand per service or client.

cli (argparse) -> typed config -> service lifecycle (``ersac_hil.lifecycle.serve``).
``sim`` runs the firmware simulator in its own process (``python -m firmware_sim``): the
agent's package never imports the simulator.
"""
from __future__ import annotations

from ersac_hil.lifecycle import note_early_interrupts, take_early

note_early_interrupts()  # first: a Ctrl-C during the imports below is never lost (lifecycle)

import argparse  # noqa: E402
import logging  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

import ersac_hil
from ersac_hil.cli_args import Parser, UsageError, fail, positive_float, positive_int, tcp_port
from protocol.can.busload import bus_load, format_report
from protocol.robot.cli import add_description_argument


def _bus_load(args: argparse.Namespace) -> int:
    load = bus_load(args.rate, args.bitrate, description=args.description)
    if not load.fits:
        raise UsageError(f"the schedule of {args.description.name} needs {load.percent:.0f} % of a "
                         f"{load.bitrate} bit/s bus at {load.rate_hz:g} Hz, more than the bus carries: "
                         f"at least {load.min_bitrate:.0f} bit/s, or at most {load.max_rate_hz:.0f} Hz")
    print(format_report(load))
    return 0 if load.within_budget or not args.check else 1


class _HubService:
    def __init__(self, port: int, monitor: bool) -> None:
        self.port, self.monitor, self.hub, self._mon = port, monitor, None, None

    def start(self) -> None:
        from ersac_hil.canbus.hub import LoopbackHub
        self.hub = LoopbackHub(self.port)
        if self.monitor:
            from ersac_hil.canbus.monitor import BusMonitor
            self._mon = BusMonitor(self.hub.bus_config).start()
        print(f"CAN hub: {self.hub.url}", flush=True)  # ready: the monitor hears every frame from now on

    def stop(self) -> None:
        if self._mon is not None:
            self._mon.stop()
        if self.hub is not None:
            self.hub.close()
        print("CAN hub stopped", flush=True)


def _bus(args: argparse.Namespace) -> int:
    from ersac_hil.lifecycle import serve
    return serve(_HubService(args.port, args.monitor))


def _exec_sim(sim_args: list[str]) -> int:
    os.execv(sys.executable, [sys.executable, "-m", "firmware_sim", *sim_args])
    return 1  # not reached


def _sim(args: argparse.Namespace) -> int:
    return _exec_sim(args.sim_args)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="ersac-hil", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0)
    parser.add_argument("--version", action="version", version=f"ersac-hil {ersac_hil.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("bus-load", help="worst-case bus load of a robot description's cyclic schedule "
                                        "(computed from the description, the bus is not touched)")
    add_description_argument(p)
    p.add_argument("--rate", type=positive_float, default=None,
                   help="SYNC rate in Hz (default: the description's, 200)")
    p.add_argument("--bitrate", type=positive_int, default=None,
                   help="bit/s (default: the description's, 1000000)")
    p.add_argument("--check", action="store_true", help="exit 1 above the description's budget (50 %%)")
    p.set_defaults(func=_bus_load)

    p = sub.add_parser("bus", help="loopback CAN hub (python-can-remote on 127.0.0.1)")
    p.add_argument("--port", type=tcp_port, default=0, help="TCP port (default: a free one)")
    p.add_argument("--monitor", action="store_true", help="print every frame that crosses the hub")
    p.set_defaults(func=_bus)

    p = sub.add_parser("sim", help="firmware simulator (python -m firmware_sim ...)", add_help=False)
    p.add_argument("sim_args", nargs=argparse.REMAINDER)
    p.set_defaults(func=_sim)

    for register in _extensions():
        register(sub)
    return parser


def _extensions():
    """Subcommands contributed by other modules of this package (agent, daemon, demo...)."""
    import importlib
    for name in ("ersac_hil.agent.cli", "ersac_hil.daemon.cli", "ersac_hil.demo", "ersac_hil.certs",
                 "ersac_hil.reproduce.cli", "ersac_hil.dashboard.cli",
                 "ersac_hil.agent.operator", "ersac_hil.commission.cli"):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue
            raise
        yield module.register


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    early = take_early()
    if early is not None:  # a Ctrl-C of the start-up that some finaliser swallowed
        return 128 + early
    if argv[:1] == ["sim"]:  # everything after "sim" belongs to the simulator's own parser
        return _exec_sim(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)  # a malformed command line: one line, exit 2 (cli_args.Parser)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    prog = f"{parser.prog} {args.command}"
    try:
        validate = getattr(args, "validate", None)
        if validate is not None:  # before the subcommand starts anything
            validate(args)
        return int(args.func(args) or 0)
    except UsageError as exc:
        return fail(prog, str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug or a broken machine: one line, -v for the traceback
        early = take_early()
        if early is not None:  # a Ctrl-C that an extension's import turned into its own error
            return 128 + early
        if args.verbose:
            raise
        print(f"{prog}: {type(exc).__name__}: {exc} (run with -v for the traceback)", file=sys.stderr, flush=True)
        return 1


if __name__ == "__main__":
    sys.exit(main())
