"""NMT states (CiA 301) by name: canopen's own table, the one source for both sides.

The code is the byte a heartbeat carries (the toggle bit masked off); 0 (INITIALISING) is the
boot-up message.
"""
from __future__ import annotations

from canopen.nmt import NMT_STATES

NMT_CODE: dict[str, int] = {name: code for code, name in NMT_STATES.items()}
"""``"OPERATIONAL"`` -> 5, ``"PRE-OPERATIONAL"`` -> 127, ``"STOPPED"`` -> 4, ``"INITIALISING"`` -> 0."""

INITIALISING, STOPPED, OPERATIONAL, PRE_OPERATIONAL = (
    NMT_CODE["INITIALISING"], NMT_CODE["STOPPED"], NMT_CODE["OPERATIONAL"], NMT_CODE["PRE-OPERATIONAL"])
