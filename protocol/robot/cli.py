"""``--description NAME|PATH`` (and ``--drives PROFILE``) for every command line that serves a
robot (stdlib argparse only, so that the simulator and the host share it without importing
each other)."""
from __future__ import annotations

import argparse
from typing import Any

from protocol.robot.load import DEFAULT_NAME, load_description, shipped_names
from protocol.robot.model import DescriptionError, RobotDescription

DRIVES: dict[str, str] = {"ubot-board": "ubot5", "cia402": "ubot5-cia402"}
"""``--drives PROFILE``: the shipped description of the uBot-5 on those drives."""


def description_type(text: str) -> RobotDescription:
    """argparse ``type``: the description, or the loader's one line as the parse error."""
    try:
        return load_description(text)
    except DescriptionError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


class _Drives(argparse.Action):
    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        try:
            setattr(namespace, "description", load_description(DRIVES[values]))
        except DescriptionError as exc:
            raise argparse.ArgumentError(self, str(exc)) from None


def add_description_argument(parser: argparse.ArgumentParser, drives: bool = False) -> None:
    """``--description NAME|PATH`` (default ``ubot5``), loaded and checked while the command
    line is parsed: a bad description stops the command before it starts anything (exit 2).
    ``drives``: also ``--drives ubot-board|cia402``, the uBot-5 on those drives (shorthand for
    ``--description ubot5`` / ``ubot5-cia402``; not both)."""
    group = parser.add_mutually_exclusive_group() if drives else parser
    group.add_argument("--description", type=description_type, default=DEFAULT_NAME, metavar="NAME|PATH",
                       help=f"robot description: a shipped one ({', '.join(shipped_names())}; "
                            f"default {DEFAULT_NAME}) or a .toml file")
    if drives:
        group.add_argument("--drives", choices=tuple(DRIVES), action=_Drives,
                           help="the uBot-5 on these drives (--description "
                                + " / ".join(DRIVES.values()) + ")")
