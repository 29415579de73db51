"""``--description NAME|PATH`` for every command line that serves a robot (stdlib argparse only,
so that the simulator and the host share it without importing each other)."""
from __future__ import annotations

import argparse

from protocol.robot.load import DEFAULT_NAME, load_description, shipped_names
from protocol.robot.model import DescriptionError, RobotDescription


def description_type(text: str) -> RobotDescription:
    """argparse ``type``: the description, or the loader's one line as the parse error."""
    try:
        return load_description(text)
    except DescriptionError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_description_argument(parser: argparse.ArgumentParser) -> None:
    """``--description NAME|PATH`` (default ``ubot5``), parsed and checked while the command
    line is: a bad description stops the command before it starts anything (exit 2)."""
    parser.add_argument("--description", type=description_type, default=DEFAULT_NAME, metavar="NAME|PATH",
                        help=f"robot description: a shipped one ({', '.join(shipped_names())}; "
                             f"default {DEFAULT_NAME}) or a .toml file")
