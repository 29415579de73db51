"""``ersac-hil agent``: the robot-side agent process (picked up by ``ersac_hil.cli``)."""
from __future__ import annotations

import argparse
import logging

from ersac_hil.cli_args import UsageError, add_prefix_argument, fail, positive_float, positive_int, usable_bus

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("agent", help="robot-side agent: Zenoh episode/run -> CANopen robot")
    p.add_argument("--robot", required=True, help="robot name (key chunk), e.g. ubot1")
    add_prefix_argument(p)
    p.add_argument("--bus-interface", help="python-can interface (socketcan, remote, virtual)")
    p.add_argument("--bus-channel", help="vcan0 / can0 / ws://127.0.0.1:PORT/ ...")
    p.add_argument("--bitrate", type=positive_int, default=None)
    p.add_argument("--bus-kwargs", dest="bus_kwargs", nargs="+", metavar="KEY=VALUE",
                   help="further arguments of the python-can interface, e.g. zenoh_config=agent.json5")
    from ersac_hil.zenoh_session import add_zenoh_arguments
    add_zenoh_arguments(p)
    p.add_argument("--mode", choices=("client", "peer"), default="client",
                   help="zenoh session mode (default client, through a router)")
    p.add_argument("--record-can", dest="record_can", metavar="DIR",
                   help="write each episode's CAN traffic to DIR/<episode_id>.blf (or .asc)")
    p.add_argument("--record-format", dest="record_format", choices=("blf", "asc"), default="blf",
                   help="CAN trace format (default blf)")
    p.add_argument("--record-series", dest="record_series", metavar="DIR",
                   help="write each episode's per-cycle time series to DIR/<episode_id>.npz "
                        "(after its reply; ersac-hil report draws them)")
    from ersac_hil.ros2 import options as ros2
    ros2.add_arguments(p)
    pacing = p.add_mutually_exclusive_group()
    pacing.add_argument("--realtime", action="store_true",
                        help="pace SYNC by the wall clock (the default on every bus that is not a "
                             "simulated bench)")
    pacing.add_argument("--lockstep", action="store_true",
                        help="the next SYNC as soon as the simulator answered (the default on a "
                             "simulated bench; refused on any other bus)")
    p.add_argument("--description", default="ubot5",
                   help="robot description: a shipped NAME (ubot5, ubot5-cia402) or a TOML file; the "
                        "setpoint limits come from it, and on a physical bus the commissioning record")
    p.add_argument("--commission-record", dest="commission_record", metavar="FILE",
                   help="the record 'ersac-hil commission' wrote (default: the state directory, docs/deploy.md)")
    p.add_argument("--keep-awake", dest="keep_awake", action="store_true",
                   help="real time only: one SCHED_IDLE spinning child per core keeps idle cores from "
                        "halting (virtual machines, kernels without a cpuidle driver; docs/performance.md)")
    p.add_argument("--period-ms", type=positive_float, default=None,
                   help="control period (default: the description's SYNC period, 5 ms)")
    p.add_argument("--deadline-ms", type=positive_float, default=250.0,
                   help="how long a SYNC cycle waits for its TPDOs (default 250 ms)")
    p.add_argument("--heartbeat-timeout-ms", type=positive_float, default=600.0,
                   help="a node silent this long is lost (default 600 ms)")
    p.set_defaults(func=_run, validate=_validate)


def _validate(args: argparse.Namespace) -> None:
    """The robot's key space, and a bus that opens (before any session or thread starts)."""
    from protocol.zenoh import KeySpace
    from protocol.robot import DescriptionError, load_description
    try:
        KeySpace(args.robot, args.prefix)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        args.loaded = load_description(args.description)
        from ersac_hil.agent.layout import RobotLayout
        RobotLayout.of(args.loaded)  # the uBot's joints on its nodes, before anything reads them
        from ersac_hil.agent.limits import SetpointLimits
        args.limits = SetpointLimits.from_description(args.loaded)
        from ersac_hil.agent.robot import RobotParameters
        args.robot_limits = RobotParameters.from_description(args.loaded)
    except (DescriptionError, OSError, ValueError) as exc:
        raise UsageError(f"--description: {exc}") from None
    if args.lockstep:  # before the bus is opened: a physical bus is refused as such
        from ersac_hil.agent.safety import lockstep_refusal, physical_bus
        from protocol.can.busconfig import BusConfigError, parse_bus_kwargs, resolve_bus_config
        try:
            bus = resolve_bus_config(args.bus_interface, args.bus_channel, args.bitrate,
                                     parse_bus_kwargs(args.bus_kwargs))
        except BusConfigError as exc:
            raise UsageError(str(exc)) from None
        why = physical_bus(bus)
        if why is not None:
            raise UsageError(lockstep_refusal(bus, why))
    usable_bus(args.bus_interface, args.bus_channel, args.bitrate, args.bus_kwargs)
    from ersac_hil.ros2.options import from_args
    from_args(args)


def _run(args: argparse.Namespace) -> int:
    from ersac_hil.agent.bus import BusTiming
    from ersac_hil.agent.episode import EpisodeConfig
    from ersac_hil.agent.safety import physical_bus
    from ersac_hil.agent.service import AgentConfig, AgentService
    from ersac_hil.agent.tasks import default_tasks
    from ersac_hil.lifecycle import serve
    from ersac_hil.ros2.options import from_args as ros2_options
    from protocol.can.busconfig import BusConfigError, parse_bus_kwargs, resolve_bus_config

    awake = None  # KeepAwake of --keep-awake
    try:
        bus = resolve_bus_config(args.bus_interface, args.bus_channel, args.bitrate,
                                 parse_bus_kwargs(args.bus_kwargs), default_bitrate=args.loaded.bus.bitrate)
        real = physical_bus(bus) is not None
        pacing = "realtime" if args.realtime else "lockstep" if args.lockstep else "auto"
        period_ms = args.loaded.bus.sync_period_ms if args.period_ms is None else args.period_ms
        timing = BusTiming(period_s=period_ms / 1000.0, deadline_s=args.deadline_ms / 1000.0,
                           heartbeat_timeout_s=args.heartbeat_timeout_ms / 1000.0,
                           realtime=args.realtime or real)
        if args.keep_awake and not timing.realtime:
            raise ValueError("--keep-awake is for real time (--realtime or a physical bus); lock-step never "
                             "waits on a timer")
        if timing.realtime:  # before the bus and the Zenoh session exist: their threads inherit it
            from protocol.can.realtime import KeepAwake, request_realtime
            print(f"agent: {request_realtime()}", flush=True)
            if args.keep_awake:
                awake = KeepAwake()
                print(f"agent: {awake.start()}", flush=True)
        config = AgentConfig(robot=args.robot, prefix=args.prefix, bus=bus,
                             zenoh_connect=tuple(args.zenoh or ()), zenoh_mode=args.mode,
                             zenoh_config=args.zenoh_config, zenoh_insecure=args.insecure,
                             record_can=args.record_can, record_format=args.record_format,
                             record_series=args.record_series,
                             ros2=ros2_options(args), record=args.record,
                             timing=timing, pacing=pacing,
                             episode=EpisodeConfig(tasks=default_tasks(args.robot_limits), robot=args.robot_limits,
                                                   limits=args.limits),
                             description=args.loaded, commission_record=args.commission_record)
        from ersac_hil.zenoh_session import ZenohOptions, resolve_config
        resolve_config(ZenohOptions(config.zenoh_connect, config.zenoh_config, config.zenoh_insecure),
                       mode=config.zenoh_mode)  # refuse a bad or insecure session config up front
        service = AgentService(config)
    except (BusConfigError, ValueError) as exc:
        if awake is not None:
            awake.close()
        return fail("ersac-hil agent", str(exc))

    class _Announcing:
        def start(self) -> None:
            from protocol.can.realtime import quiet_gc
            service.start()
            quiet_gc()
            print(f"agent ready: {service.keys.root} on {bus.describe()}, {_pacing_line(pacing, real)}",
                  flush=True)
            if service.uncommissioned is not None:
                print(f"agent: refusing episodes: {service.uncommissioned}", flush=True)

        def stop(self) -> None:
            service.stop()
            print(f"agent stopped after {service.episodes} episodes", flush=True)

    from ersac_hil.agent.errors import AgentFault
    from ersac_hil.zenoh_session import ZenohSessionError
    try:
        return serve(_Announcing())
    except (ZenohSessionError, AgentFault) as exc:
        print(f"ersac-hil agent: {exc}", flush=True)
        return 1
    finally:
        if awake is not None:
            awake.close()


def _pacing_line(pacing: str, real: bool) -> str:
    if pacing != "auto":
        return pacing.replace("lockstep", "lock-step").replace("realtime", "real time")
    if real:
        return "real time (a physical bus)"
    return "lock-step on a simulated bench, real time without a test bench"
