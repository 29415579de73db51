"""``ersac-hil dashboard``: the live web dashboard of one robot's learner.

A Zenoh client of the control plane (:class:`~ersac_hil.dashboard.bridge.Bridge`) behind a
small web server (:class:`~ersac_hil.dashboard.server.WebServer`); runs until SIGINT/SIGTERM.
Prints ``dashboard: http://HOST:PORT/`` once it serves.

It acts with the identity of its Zenoh configuration: with a role certificate other than the
operator's (``ersac-hil certs init``: observer, daemon, agent...) the page is read-only, as the
router would drop that identity's controls anyway; a plain loopback session (no certificate)
or the operator's may steer, unless ``--read-only``.

Exit codes: 0 after a clean stop (128+N after signal N), 1 the web address cannot be bound or
no Zenoh router answers, 2 invalid arguments.
"""
from __future__ import annotations

import argparse
import ipaddress
import sys

from ersac_hil.cli_args import add_prefix_argument
from ersac_hil.zenoh_session import ZenohOptions, add_zenoh_arguments, zenoh_options

__all__ = ["register", "DashboardService", "DEFAULT_PORT", "CONTROL_ROLES", "is_read_only"]

DEFAULT_PORT = 8050
#: Certificate roles whose dashboards have controls (the only role the access control lets steer).
CONTROL_ROLES = ("operator",)


def is_read_only(role: str | None, read_only_flag: bool) -> bool:
    """Whether a dashboard acting as ``role`` (None: no certificate) shows no controls."""
    return read_only_flag or (role is not None and role not in CONTROL_ROLES)


class DashboardService:
    """The dashboard as a ``lifecycle.Service``.

    Args:
        robot, prefix: whose control plane (``<prefix>/<robot>/learner/...``).
        zenoh_options: Zenoh endpoints / json5 config (the identity the dashboard acts with).
        host, port: web address (port 0: a free one).
        read_only: no controls on the page, control endpoints answer 403.
        role: the certificate role of ``zenoh_options`` (shown; None: no certificate).
        critic_points: points per parameter of the critic view.
        timeout_s: per-request timeout towards the learner.
    """

    def __init__(self, robot: str, prefix: str, zenoh_options: ZenohOptions, host: str, port: int, *,
                 read_only: bool = False, critic_points: int = 41, timeout_s: float = 10.0,
                 role: str | None = None) -> None:
        self.robot, self.prefix, self.zenoh_options = robot, prefix, zenoh_options
        self.host, self.port = host, port
        self.read_only, self.critic_points, self.timeout_s = read_only, critic_points, timeout_s
        self.role = role
        self.bridge = None
        self.server = None

    def start(self) -> None:
        from protocol.zenoh import KeySpace

        from .bridge import Bridge
        from .model import DashboardModel
        from .server import EventHub, WebServer, build_app, is_loopback

        keys = KeySpace(self.robot, self.prefix)
        hub = EventHub(lambda: self.bridge.snapshot())
        self.bridge = Bridge(keys, self.zenoh_options, DashboardModel(self.robot, self.read_only), hub.publish,
                             critic_points=self.critic_points, timeout_s=self.timeout_s)
        loopback = is_loopback(self.host)
        app = build_app(self.bridge, hub, read_only=self.read_only, loopback=loopback)
        self.server = WebServer(app, hub, self.host, self.port).start()
        self.bridge.start()
        print(f"dashboard: {self.server.url} (robot {self.robot}"
              f"{f', role {self.role}' if self.role else ''}{', read-only' if self.read_only else ''})",
              flush=True)
        if not loopback and not self.read_only:
            print(f"ersac-hil: warning: the dashboard listens on {self.host}: whoever reaches it can "
                  "steer the learner with this dashboard's Zenoh identity", file=sys.stderr, flush=True)

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
        if self.bridge is not None:
            self.bridge.close()
        print("dashboard stopped", flush=True)


def _fail(message: str, code: int) -> int:
    print(f"ersac-hil: {message}", file=sys.stderr, flush=True)
    return code


def _dashboard(args: argparse.Namespace) -> int:
    from ersac_hil.certs import CertError, role_of_config
    from ersac_hil.lifecycle import serve
    from ersac_hil.zenoh_session import ZenohConfigError, ZenohSessionError
    from protocol.zenoh import GRID_MAX, KeySpace, KeySpaceError

    try:
        ipaddress.ip_address(args.host)
    except ValueError:
        return _fail(f"--host {args.host!r} is not an IP address", 2)
    if not 0 <= args.port <= 65535:
        return _fail(f"--port {args.port} is not in 0..65535", 2)
    if not 2 <= args.critic_points <= GRID_MAX:
        return _fail(f"--critic-points {args.critic_points} is not in 2..{GRID_MAX}", 2)
    try:
        KeySpace(args.robot, args.prefix)
    except KeySpaceError as exc:
        return _fail(str(exc), 2)
    options = zenoh_options(args)
    try:
        role = role_of_config(options.config_file) if options.config_file else None
    except CertError as exc:
        return _fail(str(exc), 2)
    service = DashboardService(args.robot, args.prefix, options, args.host, args.port,
                               read_only=is_read_only(role, args.read_only), critic_points=args.critic_points,
                               timeout_s=args.timeout, role=role)
    try:
        return serve(service)
    except ZenohConfigError as exc:
        return _fail(str(exc), 2)
    except ZenohSessionError as exc:
        return _fail(str(exc), 1)
    except OSError as exc:
        return _fail(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc}", 1)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``dashboard`` to the ``ersac-hil`` parser."""
    p = sub.add_parser("dashboard", help="live web dashboard: learning curve, critic, state, controls",
                       description="Serve a live dashboard of one robot's learner (a Zenoh client "
                                   "of its control plane) on http://HOST:PORT/.")
    p.add_argument("--robot", default="ubot1", help="robot name (default ubot1)")
    add_prefix_argument(p)
    add_zenoh_arguments(p)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port to listen on (default {DEFAULT_PORT}; 0 = a free one)")
    p.add_argument("--read-only", action="store_true",
                   help="no controls: the page only shows, control endpoints answer 403 "
                        "(always so with a certificate of another role than operator)")
    p.add_argument("--critic-points", type=int, default=41, metavar="N",
                   help="critic points per parameter (default 41)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds per learner request (default 10)")
    p.set_defaults(func=_dashboard)
