"""Reading a TOML file, with one line naming the file and the cause when it cannot be read.

Every TOML input goes through :func:`read_toml`: the robot description (``protocol.robot``),
the simulator's physics overrides (``firmware_sim.plant.overrides``) and the daemon's config
file (``ersac_hil.daemon.config``); each passes its own error type.
"""
from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_toml"]


def read_toml(path: str | Path, error: type[Exception], what: str = "") -> dict[str, Any]:
    """The top-level table of the TOML file ``path``.

    Raises:
        error: ``"<what><path>: cannot read it (<why>)"`` (missing, a directory, no permission)
            or ``"<what><path>: not valid TOML: <where>"`` (a syntax error, not UTF-8).
    """
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise error(f"{what}{path}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{what}{path}: not valid TOML: not UTF-8 (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what}{path}: not valid TOML: {exc}") from None
