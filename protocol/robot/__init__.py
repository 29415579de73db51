"""The robot description: which nodes and axes a robot has, their drives, constants and limits,
and the bus schedule (bit rate, SYNC period), read from a TOML file (docs/robot_description.md).

* ``load_description(name_or_path)`` - a shipped description (``ubot5``, ``ubot5-cia402``) or a file
* ``default_description()``          - ``ubot5``, the uBot-5 on its own boards (the paper's robot)
* ``RobotDescription``, ``Axis``, ``Bus``, ``Node``, ``ImuNode``, ``BenchNode``, ``Range``, ``ObjectRef``
* ``DescriptionError``               - a bad description, one line naming the field
"""
from protocol.robot.load import DEFAULT_NAME, default_description, load_description, shipped_names
from protocol.robot.model import (MODES, PROFILES, Axis, BenchNode, Bus, DescriptionError, Device, ImuNode,
                                  Node, ObjectRef, Range, RobotDescription)

__all__ = ["DEFAULT_NAME", "MODES", "PROFILES", "Axis", "BenchNode", "Bus", "DescriptionError", "Device",
           "ImuNode", "Node", "ObjectRef", "Range", "RobotDescription", "default_description",
           "load_description", "shipped_names"]
