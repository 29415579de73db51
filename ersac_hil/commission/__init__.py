"""Commissioning a robot before its first episode (``ersac-hil commission``).

``scan`` reads the bus by SDO and heartbeats without moving anything, ``checks`` compares it with
the robot description (pure), ``run`` is the pass that ties them together, ``fingerprint`` the
record the agent checks before it serves episodes on a physical bus, ``move`` the one-axis
motion test, ``cli`` the command.
"""
