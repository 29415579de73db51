"""The uBot-5's CANopen devices and the simulator's test bench: which exist, their node-ids,
and their EDS files.

``DEVICES`` is the single table of node assignments. ``object_dictionary(device)`` loads the
device's EDS with canopen (cached per device).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import canopen
from canopen.objectdictionary import ObjectDictionary

AGENT_NODE_ID = 0x01
"""The agent (NMT master, SYNC producer) produces its heartbeat under this node-id."""

HEARTBEAT_PERIOD_MS = 100
"""Producer heartbeat period of every node, and of the agent."""

CONSUMER_HEARTBEAT_MS = 250
"""How long a controller tolerates silence from the agent before its safe state (0x1016)."""


@dataclass(frozen=True)
class Device:
    """One CANopen node.

    ``axes`` names the motor axes in sub-index order (sub-index 1 = ``axes[0]``).
    ``joints`` are the robot-level names of those axes (what the simulator calls them).
    ``simulated_only`` marks nodes that exist only on a simulated robot (the test bench).
    """
    name: str
    node_id: int
    eds: str
    axes: tuple[str, ...] = ()
    joints: tuple[str, ...] = ()
    simulated_only: bool = False

    @property
    def eds_path(self) -> Path:
        return eds_path(self.eds)


WHEELS = Device("wheels", 0x10, "wheel.eds", ("left", "right"), ("wheel_left", "wheel_right"))
TORSO = Device("torso", 0x11, "torso.eds", ("torso",), ("torso",))
ARM_LEFT = Device("arm_left", 0x12, "arm.eds", ("shoulder", "elbow"), ("shoulder_left", "elbow_left"))
ARM_RIGHT = Device("arm_right", 0x13, "arm.eds", ("shoulder", "elbow"), ("shoulder_right", "elbow_right"))
IMU = Device("imu", 0x20, "imu.eds")
TESTBENCH = Device("testbench", 0x7E, "testbench.eds", simulated_only=True)

DEVICES: tuple[Device, ...] = (WHEELS, TORSO, ARM_LEFT, ARM_RIGHT, IMU, TESTBENCH)
"""Every node of a simulated uBot, in node-id order."""

ROBOT: tuple[Device, ...] = tuple(d for d in DEVICES if not d.simulated_only)
"""The nodes a real robot has."""


def device(name_or_id: str | int) -> Device:
    """Look a device up by name (``"arm_left"``) or node-id."""
    for d in DEVICES:
        if d.name == name_or_id or d.node_id == name_or_id:
            return d
    raise KeyError(f"no device {name_or_id!r} on the uBot; known: {[d.name for d in DEVICES]}")


def eds_path(filename: str) -> Path:
    path = Path(str(resources.files("protocol.can") / "eds" / filename))
    if not path.is_file():
        raise FileNotFoundError(f"EDS file {filename} is not in protocol/can/eds")
    return path


@functools.lru_cache(maxsize=None)
def _od(filename: str, node_id: int) -> ObjectDictionary:
    return canopen.import_od(str(eds_path(filename)), node_id)


def object_dictionary(dev: Device) -> ObjectDictionary:
    """The device's object dictionary, parsed from its EDS with ``$NODEID`` resolved.

    Shared and cached: treat it as read-only (canopen nodes only read their OD).
    """
    return _od(dev.eds, dev.node_id)
