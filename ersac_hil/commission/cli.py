"""``ersac-hil commission``: check a robot's bus against its description; moves nothing unless
``--move AXIS`` (and then one axis, a little, after a typed confirmation).

Exit status: 0 the bus is the description's robot (the record is written: the agent may serve
episodes), 1 defects (each on one line), 2 usage (a bad description, a bus that does not open).
"""
from __future__ import annotations

import argparse
import sys

from ersac_hil.cli_args import UsageError, fail, positive_float, positive_int, usable_bus

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("commission", help="check the bus against the robot description (moves nothing)")
    p.add_argument("--description", default="ubot5",
                   help="robot description: a shipped NAME (ubot5, ubot5-cia402) or a TOML file")
    p.add_argument("--bus-interface", help="python-can interface (socketcan, remote, virtual, zenoh)")
    p.add_argument("--bus-channel", help="can0 / vcan0 / ws://127.0.0.1:PORT/ ...")
    p.add_argument("--bitrate", type=positive_int, default=None)
    p.add_argument("--bus-kwargs", dest="bus_kwargs", nargs="+", metavar="KEY=VALUE",
                   help="further arguments of the python-can interface")
    p.add_argument("--commission-record", dest="record", metavar="FILE",
                   help="where the passed record goes (default: the state directory, docs/deploy.md)")
    p.add_argument("--listen-ms", dest="listen_ms", type=positive_float, default=350.0,
                   help="how long to listen for heartbeats (default 350 ms: three heartbeat periods)")
    p.add_argument("--sdo-timeout-ms", dest="sdo_timeout_ms", type=positive_float, default=300.0,
                   help="how long a node may take to answer one SDO read (default 300 ms)")
    p.add_argument("--move", metavar="AXIS",
                   help="after a pass: enable this axis at low stiffness and move it a little "
                        "(asks for a typed confirmation)")
    p.add_argument("--yes-move", dest="confirm", metavar="AXIS",
                   help="the confirmation of --move given on the command line (the axis name again)")
    p.set_defaults(func=_run, validate=_validate)


def _validate(args: argparse.Namespace) -> None:
    from protocol.robot import DescriptionError, load_description
    try:
        args.loaded = load_description(args.description)
    except (DescriptionError, OSError) as exc:
        raise UsageError(f"--description: {exc}") from None
    if args.move is not None and args.move not in args.loaded.joints:
        raise UsageError(f"--move {args.move}: no such axis in {args.loaded.name} "
                         f"(axes: {', '.join(args.loaded.joints)})")
    args.bus = usable_bus(args.bus_interface, args.bus_channel, args.bitrate, args.bus_kwargs)


def _run(args: argparse.Namespace) -> int:
    from ersac_hil.commission.fingerprint import record_path, write_record
    from ersac_hil.commission.run import commission
    description = args.loaded
    report = commission(description, args.bus, listen_s=args.listen_ms / 1000.0,
                        sdo_timeout_s=args.sdo_timeout_ms / 1000.0)
    print(report.text(), flush=True)
    if not report.passed:
        return 1
    path = record_path(description, args.record)
    try:
        write_record(path, description, report.bus, report.fingerprint,
                     (i for i in report.identities if i.node_id in {d.node_id for d in description.robot_devices}))
    except OSError as exc:
        return fail("ersac-hil commission", f"cannot write the record {path}: {exc}")
    print(f"record: {path}", flush=True)
    if args.move is None:
        return 0
    from ersac_hil.commission.move import MoveRefused, move_axis
    answer = args.confirm if args.confirm is not None else _ask(args.move)
    if answer != args.move:
        print(f"ersac-hil commission: --move {args.move} not confirmed (typed {answer!r}): nothing moved",
              file=sys.stderr, flush=True)
        return 1
    try:
        for line in move_axis(description, args.bus, args.move, sdo_timeout_s=args.sdo_timeout_ms / 1000.0):
            print(line, flush=True)
    except MoveRefused as exc:
        print(f"ersac-hil commission: --move {args.move}: {exc}", file=sys.stderr, flush=True)
        return 1
    return 0


def _ask(axis: str) -> str:
    print(f"--move {axis}: the axis will be enabled at low stiffness and move by a small angle and back.\n"
          f"Clear the robot, keep a hand on the e-stop, and type the axis name ({axis}) to go on: ",
          end="", flush=True)
    try:
        return input().strip()
    except EOFError:
        return ""
