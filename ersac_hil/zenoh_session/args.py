"""Command-line plumbing: the ``--zenoh``/``--zenoh-config``/``--insecure`` flags of every
command and the :class:`ZenohOptions` they give."""
from __future__ import annotations

import argparse

from .config import ZenohOptions
from .endpoints import DEFAULT_ENDPOINT

__all__ = ["add_zenoh_arguments", "zenoh_argv", "zenoh_options"]


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, listens: bool = False) -> None:
    """``--zenoh ENDPOINT`` (repeatable), ``--zenoh-config FILE``, ``--insecure``."""
    where = "listen on" if listens else "connect to"
    parser.add_argument(
        "--zenoh", action="append", metavar="ENDPOINT",
        help=f"endpoint to {where}, repeatable (default: the --zenoh-config file's, else "
             f"{DEFAULT_ENDPOINT}); off loopback only tls/HOST:PORT unless --insecure")
    parser.add_argument(
        "--zenoh-config", dest="zenoh_config", metavar="FILE",
        help="Zenoh json5 configuration (TLS certificates, access control...); "
             "ersac-hil certs init writes one per role")
    parser.add_argument(
        "--insecure", action="store_true",
        help="allow plain (unencrypted, unauthenticated) endpoints off loopback")


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """The :class:`ZenohOptions` of parsed :func:`add_zenoh_arguments` flags."""
    return ZenohOptions(tuple(args.zenoh or ()), args.zenoh_config, bool(args.insecure))


def zenoh_argv(options: ZenohOptions) -> list[str]:
    """The :func:`add_zenoh_arguments` flags that give ``options`` (a child process's command line)."""
    argv = [arg for ep in options.endpoints for arg in ("--zenoh", ep)]
    if options.config_file is not None:
        argv += ["--zenoh-config", options.config_file]
    return argv + (["--insecure"] if options.insecure else [])
