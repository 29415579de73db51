"""The default robot's CANopen devices (the uBot-5 on its boards, and the simulator's test
bench): which exist, their node-ids, and their EDS files - as its robot description
(protocol/robots/ubot5.toml, read by ``protocol.robot``) gives them.

``DEVICES`` is the default description's table of nodes; a program that serves another
description takes ``description.devices`` instead. ``object_dictionary(device)`` loads the
device's EDS with canopen (cached per EDS file and node-id).
"""
from __future__ import annotations

from canopen.objectdictionary import ObjectDictionary

from protocol.robot import default_description
from protocol.robot.eds import object_dictionary_file
from protocol.robot.model import Device, eds_path

__all__ = ["AGENT_NODE_ID", "ARM_LEFT", "ARM_RIGHT", "BITRATE", "CONSUMER_HEARTBEAT_MS", "DEVICES",
           "HEARTBEAT_PERIOD_MS", "IMU", "ROBOT", "SYNC_PERIOD_S", "TESTBENCH", "TORSO", "WHEELS",
           "Device", "device", "eds_path", "object_dictionary"]

_DEFAULT = default_description()

AGENT_NODE_ID = _DEFAULT.bus.agent_node_id
"""The agent (NMT master, SYNC producer) produces its heartbeat under this node-id."""

HEARTBEAT_PERIOD_MS = _DEFAULT.bus.heartbeat_period_ms
"""Producer heartbeat period of every node, and of the agent."""

CONSUMER_HEARTBEAT_MS = _DEFAULT.bus.consumer_heartbeat_ms
"""How long a controller tolerates silence from the agent before its safe state (0x1016)."""

SYNC_PERIOD_S = _DEFAULT.bus.sync_period_s
"""The control period, one SYNC every 5 ms (200 Hz): the default of every program's period
(the simulator's step, the agent's SYNC in real time), each with its command-line override."""

BITRATE = _DEFAULT.bus.bitrate
"""The bus's bit rate [bit/s] (1 Mbit/s), the default where a CAN interface needs one."""

DEVICES: tuple[Device, ...] = _DEFAULT.devices
"""Every node of a simulated uBot, in node-id order."""

ROBOT: tuple[Device, ...] = _DEFAULT.robot_devices
"""The nodes a real robot has."""

WHEELS, TORSO, ARM_LEFT, ARM_RIGHT, IMU, TESTBENCH = (
    _DEFAULT.device(n) for n in ("wheels", "torso", "arm_left", "arm_right", "imu", "testbench"))


def device(name_or_id: str | int) -> Device:
    """Look a device of the default robot up by name (``"arm_left"``) or node-id."""
    return _DEFAULT.device(name_or_id)


def object_dictionary(dev: Device) -> ObjectDictionary:
    """The device's object dictionary, parsed from its EDS with ``$NODEID`` resolved.

    Shared and cached: treat it as read-only (canopen nodes only read their OD).
    """
    return object_dictionary_file(dev.eds, dev.node_id)
