"""Where the uBot's joints are on a robot's CANopen nodes: read from its robot description.

The agent's commands and telemetry are the uBot's, whatever drives carry them: the joints in
``JOINTS`` order (wheels, torso, two two-joint arms) and a status word per part of the robot
(``PARTS``, then the IMU's). Which node and sub-index carries each joint, which node takes which
part's commands, which nodes a SYNC cycle waits for, and which node is an arm's (its impedance,
its spline): the description's nodes and axes, matched by joint name, not tables in code.

    layout = RobotLayout.of(load_description("ubot5"))
    layout.joint_index[("arm_left", 2)]     # -> 4: elbow_left, the arm board's second axis
    layout.arm("left").name                 # -> "arm_left"
"""
from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from protocol.robot import RobotDescription, default_description
from protocol.robot.model import Device

PARTS: dict[str, tuple[str, ...]] = {
    "wheels": ("wheel_left", "wheel_right"),
    "torso": ("torso",),
    "arm_left": ("shoulder_left", "elbow_left"),
    "arm_right": ("shoulder_right", "elbow_right"),
}
"""The uBot's parts and their joints, in telemetry order."""
JOINTS: tuple[str, ...] = tuple(j for joints in PARTS.values() for j in joints)
"""Joint names in telemetry order, shape ``(7,)``."""
IMU_PART = "imu"
STATUS_PARTS: tuple[str, ...] = (*PARTS, IMU_PART)
"""What each status word of the telemetry is of (``Telemetry.status`` order)."""
_PART_OF_JOINT = {j: part for part, joints in PARTS.items() for j in joints}


@dataclass(frozen=True)
class RobotLayout:
    """The uBot's joints on one robot's nodes.

    Attributes:
        actuated: the nodes that carry joints (commands out, axis telemetry in), node-id order.
        imu: the IMU node.
        cyclic: the nodes with synchronous TPDOs, what every SYNC cycle waits for: the actuated
            ones and the IMU.
        joint_index: (node name, axis sub-index) -> position in ``JOINTS``.
        part_of: node name -> the part (``PARTS``) its joints belong to.
        status_nodes: per ``STATUS_PARTS``, the nodes whose status makes that part's word
            (one board, or one CiA 402 drive per joint of the part).
    """
    actuated: tuple[Device, ...]
    imu: Device
    cyclic: tuple[Device, ...]
    joint_index: Mapping[tuple[str, int], int]
    part_of: Mapping[str, str]
    status_nodes: tuple[tuple[str, ...], ...]

    def board(self, part: str) -> Device:
        """The one node of ``part`` (a ``STATUS_PARTS`` name) on a robot whose part is one node,
        as on the uBot boards; ``ValueError`` where it is not."""
        names = self.status_nodes[STATUS_PARTS.index(part)]
        if len(names) != 1:
            raise ValueError(f"the {part} of this robot are on {len(names)} nodes, not one board")
        return next(d for d in self.cyclic if d.name == names[0])

    def arm(self, side: str) -> Device:
        """The board of the arm ``side`` ("left"/"right"): ``board("arm_<side>")``."""
        return self.board(f"arm_{side}")

    @property
    def arms(self) -> tuple[Device, ...]:
        return (self.arm("left"), self.arm("right"))

    @classmethod
    def of(cls, description: RobotDescription, devices: Iterable[Device] | None = None) -> "RobotLayout":
        """The layout of ``description`` (``devices``: those of its nodes the bus has, default
        all); ``ValueError`` naming the joint when the uBot's joints are not each on one node,
        or a node carries joints of two parts."""
        devices = tuple(description.devices if devices is None else devices)
        actuated = tuple(d for d in devices if d.joints)
        carried = [j for d in description.devices for j in d.joints]
        for joint in JOINTS:
            if carried.count(joint) != 1:
                raise ValueError(f"{description.name}: joint {joint} is on {carried.count(joint)} nodes, "
                                 "the agent needs it on one")
        part_of: dict[str, str] = {}
        for d in actuated:
            parts = {_PART_OF_JOINT.get(j) for j in d.joints}
            if len(parts) != 1 or None in parts:
                raise ValueError(f"{description.name}: node {d.name} carries {list(d.joints)}, not the joints "
                                 "of one part of the uBot")
            part_of[d.name] = parts.pop()  # type: ignore[assignment]
        index = {(d.name, sub): JOINTS.index(j) for d in actuated for sub, j in enumerate(d.joints, start=1)}
        imu = description.device(description.imu.name)
        cyclic = (*actuated, *(d for d in devices if d.name == imu.name))
        status = tuple(tuple(d.name for d in actuated if part_of[d.name] == part) for part in PARTS)
        return cls(actuated, imu, cyclic, index, part_of, (*status, (imu.name,)))


@functools.cache
def default_layout() -> RobotLayout:
    """The layout of the default description (``protocol.robot.default_description``)."""
    return RobotLayout.of(default_description())
