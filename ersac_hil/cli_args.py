"""Command-line input checked before anything starts: one clear line and exit 2 for bad input.

Every ``ersac-hil`` subcommand gets the same treatment from ``ersac_hil.cli.main``:

* ``Parser`` (the parser class of the whole tree) answers a malformed command line with one
  line, ``ersac-hil <command>: error: <what>``, and exit status 2 (argparse would print the
  usage block first);
* the argument types below refuse out-of-range values while parsing;
* a subcommand may register ``validate(args)`` (``parser.set_defaults(validate=...)``) for
  what needs more than one argument or a look at the machine (a bus that cannot be opened, a
  payload that would be refused); it raises ``UsageError`` and runs before the subcommand's
  ``func`` starts anything.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from protocol.can.busconfig import BusConfig, BusConfigError, parse_bus_kwargs, probe_bus, resolve_bus_config

EXIT_USAGE = 2


class UsageError(ValueError):
    """Bad command-line input; the message is the whole explanation (one line)."""


class Parser(argparse.ArgumentParser):
    """``argparse`` with a one-line error: ``prog: error: message`` on stderr, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def fail(prog: str, message: str) -> int:
    """Print the one-line usage error of ``prog``; returns the exit status 2."""
    print(f"{prog}: error: {message}", file=sys.stderr, flush=True)
    return EXIT_USAGE


def _number(kind: type, text: str) -> float | int:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def finite_float(text: str) -> float:
    return float(_number(float, text))


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be positive")
    return value


def non_negative_float(text: str) -> float:
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must not be negative")
    return value


def positive_int(text: str) -> int:
    value = int(_number(int, text))
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive integer")
    return value


def non_negative_int(text: str) -> int:
    value = int(_number(int, text))
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must not be negative")
    return value


def tcp_port(text: str) -> int:
    """0 (a free port) .. 65535."""
    value = int(_number(int, text))
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (0..65535)")
    return value


def output_dir(text: str) -> str:
    """A directory the command may create or write into: an existing directory, or a path
    whose nearest existing ancestor is a directory a file can be created in (tried with a
    temporary directory, removed at once: nothing is left behind). Returns ``text``."""
    path = Path(text).expanduser().absolute()
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is not a directory")
    ancestor = next(p for p in (path, *path.parents) if p.exists())
    if not ancestor.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: {ancestor} is not a directory")
    try:
        tempfile.TemporaryDirectory(dir=ancestor).cleanup()
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: cannot write in {ancestor} ({exc.strerror or exc})") from None
    return text


def file_in_dir(text: str) -> str:
    """A file path (existing or not) that is not a directory, in an ``output_dir``. Returns ``text``."""
    path = Path(text).expanduser()
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory, not a file")
    output_dir(str(path.parent))
    return text


def usable_bus(interface: str | None, channel: str | None, bitrate: int | None,
               bus_kwargs: Sequence[str] | None = None) -> BusConfig:
    """The bus configuration of the command line (``bus_kwargs``: ``--bus-kwargs KEY=VALUE``
    items), resolved and opened once to see that it works (``UsageError`` naming why not: no
    SocketCAN in the kernel, no such interface, no hub listening, ...)."""
    try:
        config = resolve_bus_config(interface, channel, bitrate, parse_bus_kwargs(bus_kwargs))
        probe_bus(config)
    except BusConfigError as exc:
        raise UsageError(str(exc)) from None
    return config


def add_prefix_argument(parser: argparse.ArgumentParser, what: str = "key prefix") -> None:
    """``--prefix``: the Zenoh key prefix, by default the contract's (``protocol.zenoh.keys``)."""
    from protocol.zenoh.keys import DEFAULT_PREFIX
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"{what} (default {DEFAULT_PREFIX})")
