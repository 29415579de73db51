"""``python -m firmware_sim`` (also ``ersac-hil sim``): the simulated robot on a CAN bus.

    python -m firmware_sim --bus-interface remote --bus-channel ws://127.0.0.1:PORT/ --seed 3
    python -m firmware_sim --snapshot out.png --scenario bracing

Runs until SIGINT/SIGTERM (awaited with ``signal.sigwait``: this package cannot use
``ersac_hil.lifecycle``), then takes every node off the bus and closes it.
"""
from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: headless rendering

import argparse  # noqa: E402
import logging  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402

_SIGNALS = {signal.SIGINT, signal.SIGTERM}


class _Parser(argparse.ArgumentParser):
    """Bad input: one line (``ersac-hil sim: error: ...``) and exit 2, no usage block."""

    def error(self, message: str):  # noqa: ANN201 - NoReturn
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="ersac-hil sim", description="MuJoCo uBot robot as CANopen nodes")
    p.add_argument("--bus-interface", help="python-can interface (virtual, remote, socketcan)")
    p.add_argument("--bus-channel", help="channel (ws://127.0.0.1:PORT/ for the loopback hub, vcan0, ...)")
    p.add_argument("--bitrate", type=int, default=None)
    p.add_argument("--bus-kwargs", dest="bus_kwargs", nargs="+", metavar="KEY=VALUE",
                   help="further arguments of the python-can interface, e.g. zenoh_config=simulator.json5")
    p.add_argument("--seed", type=int, default=0, help="seed of the idle scenario at start")
    p.add_argument("--realtime", action="store_true", help="pace physics by the wall clock")
    p.add_argument("--control-period", type=float, default=None,
                   help="s per SYNC (default: the description's SYNC period, 0.005)")
    p.add_argument("--substeps", type=int, default=5, help="physics steps per period (default 5)")
    p.add_argument("--snapshot", metavar="PNG", help="render one frame headlessly and exit")
    p.add_argument("--scenario", default="bracing", help="scenario of --snapshot")
    p.add_argument("--at", type=float, default=0.0, help="--snapshot: simulated seconds before the frame")
    p.add_argument("--physics", metavar="FILE", help="TOML of named physical overrides (docs/physics.md)")
    p.add_argument("--physics-names", action="store_true", help="list the overridable quantities and exit")
    from protocol.robot.cli import add_description_argument
    add_description_argument(p, drives=True)
    p.add_argument("-v", "--verbose", action="count", default=0)
    return p


def snapshot(path: str, scenario: str, seed: int, at: float, physics=None) -> None:  # noqa: ANN001
    """Render the scenario's state after ``at`` s (passive robot) to a PNG."""
    import mujoco
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from firmware_sim.simulator import Simulator

    sim = Simulator() if physics is None else Simulator(physics=physics)
    sim.reset(scenario, seed)
    for _ in range(int(round(at / sim.control_period))):
        sim.step()
    phys = sim.physics
    camera = mujoco.MjvCamera()
    camera.lookat[:] = phys.base_position() + [0.0, 0.0, 0.3]
    camera.distance, camera.azimuth, camera.elevation = 2.2, 120.0, -15.0
    with mujoco.Renderer(phys.model, 480, 640) as renderer:
        renderer.update_scene(phys.data, camera)
        pixels = renderer.render()
    plt.imsave(path, pixels)


def _check(parser: argparse.ArgumentParser, args: argparse.Namespace):  # noqa: ANN202
    """Refuse bad input before anything starts; returns the bus configuration (or None for
    --snapshot)."""
    import math
    from pathlib import Path

    from protocol.can.busconfig import BusConfigError, parse_bus_kwargs, probe_bus, resolve_bus_config

    from firmware_sim.plant.physics import AXES
    if set(args.description.joints) != set(AXES):
        parser.error(f"--description {args.description.name}: its axes ({', '.join(args.description.joints)}) "
                     f"are not the simulated plant's ({', '.join(AXES)})")
    if args.control_period is None:
        args.control_period = args.description.bus.sync_period_s
    if not (math.isfinite(args.control_period) and 0 < args.control_period <= 1):
        parser.error(f"--control-period must be in (0, 1] s, got {args.control_period}")
    if args.substeps < 1:
        parser.error(f"--substeps must be at least 1, got {args.substeps}")
    if args.seed < 0:
        parser.error(f"--seed must not be negative, got {args.seed}")
    from firmware_sim.plant.overrides import PhysicsError, PhysicsOverrides
    try:
        args.physics = PhysicsOverrides() if args.physics is None else PhysicsOverrides.load(args.physics)
    except PhysicsError as exc:
        parser.error(f"--physics: {exc}")
    if args.snapshot:
        from firmware_sim.scenarios import SCENARIOS
        if args.scenario not in SCENARIOS:
            parser.error(f"--scenario {args.scenario!r} is not one of {sorted(SCENARIOS)}")
        if not math.isfinite(args.at) or args.at < 0:
            parser.error(f"--at must not be negative, got {args.at}")
        if not Path(args.snapshot).resolve().parent.is_dir():
            parser.error(f"--snapshot: no directory {Path(args.snapshot).resolve().parent}")
        return None
    try:
        config = resolve_bus_config(args.bus_interface, args.bus_channel, args.bitrate,
                                    parse_bus_kwargs(args.bus_kwargs),
                                    default_bitrate=args.description.bus.bitrate)
        probe_bus(config)
    except BusConfigError as exc:
        parser.error(str(exc))
    return config


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.physics_names:
        from firmware_sim.plant.overrides import names_table
        print(names_table())
        return 0
    config = _check(parser, args)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s sim %(levelname)s %(message)s")
    if args.snapshot:
        try:
            snapshot(args.snapshot, args.scenario, args.seed, args.at, args.physics)
        except Exception as exc:  # no GL on this machine: say so plainly
            print(f"snapshot failed: {exc} (headless rendering needs MUJOCO_GL=egl with "
                  "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1, or osmesa with libosmesa6)",
                  file=sys.stderr)
            return 2
        print(f"snapshot: {args.snapshot}")
        return 0

    from firmware_sim.nodes.simrobot import SimulatedRobot

    # SIGINT/SIGTERM stay pending for sigwait below; blocked before any thread starts, so
    # every thread of the robot inherits the mask and none of them is interrupted
    signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    if args.realtime:  # before the bus and its threads exist: they inherit the policy
        from protocol.can.realtime import request_realtime
        print(f"simulator: {request_realtime()}", flush=True)
    robot = SimulatedRobot(config, seed=args.seed, realtime=args.realtime,
                           control_period=args.control_period, substeps=args.substeps, physics=args.physics,
                           description=args.description)
    from protocol.can.realtime import quiet_gc
    quiet_gc()
    mode = "real-time" if args.realtime else "lock-step"
    print(f"simulator: {len(robot.nodes)} nodes on {config.describe()}, {mode}, "
          f"{1 / args.control_period:g} Hz, {args.physics.describe()}, robot {args.description.name}", flush=True)
    try:
        received = signal.sigwait(_SIGNALS)
    finally:
        robot.close()
        s = robot.stats
        print(f"simulator stopped: {s.cycles} cycles, {s.resets} resets, {s.overruns} overruns, "
              f"physics {1000 * s.step_seconds / max(s.cycles, 1):.2f} ms/cycle", flush=True)
    return 128 + received

if __name__ == "__main__":
    sys.exit(main())
