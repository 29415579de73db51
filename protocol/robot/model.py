"""The robot description as typed, frozen structures (what ``protocol.robot.load`` builds from a
TOML file; docs/robot_description.md documents every field).

A description names the robot's CANopen nodes and, per axis (joint), the node and sub-index that
carry it, its drive profile and mode, the motor and gearbox constants and the limits the host
keeps to; the IMU node, the simulated test bench and the bus (bit rate, SYNC period, heartbeats).
Every value is in SI units (rad, rad/s, N m, A, ohm, N m/rad, N m s/rad) unless its name says
otherwise (``_ms``, ``bitrate``).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

Profile = Literal["ubot-board", "cia402"]
PROFILES: tuple[str, ...] = ("ubot-board", "cia402")

MODES: dict[str, tuple[str, ...]] = {
    "ubot-board": ("torque", "impedance"),
    "cia402": ("csp-impedance", "cst"),
}
"""Modes an axis of each profile can run in. ``ubot-board``: the board's torque mode (wheels) or
its joint impedance (torso, arms). ``cia402``: cyclic synchronous position with the drive's own
impedance gains, or cyclic synchronous torque with the impedance law on the host."""

SHIPPED_EDS_DIR = Path(__file__).resolve().parents[1] / "can" / "eds"
"""Where EDS files named without a directory are found (the EDS files this project ships)."""


class DescriptionError(ValueError):
    """A robot description that cannot be used; the message is one line naming the field."""


def eds_path(filename: str) -> Path:
    """The EDS file a description names: a bare name is one of the shipped files
    (protocol/can/eds), anything else a path (descriptions store paths resolved absolute)."""
    path = Path(filename) if Path(filename).is_absolute() else SHIPPED_EDS_DIR / filename
    if not path.is_file():
        raise FileNotFoundError(f"EDS file {filename} is not in protocol/can/eds"
                                if not Path(filename).is_absolute() else f"EDS file {filename} does not exist")
    return path


@dataclass(frozen=True)
class Range:
    """A closed interval ``[min, max]`` (``min < max``)."""
    min: float
    max: float

    def __contains__(self, value: float) -> bool:
        return self.min <= value <= self.max

    def clamp(self, value: float) -> float:
        return min(max(value, self.min), self.max)

    def as_tuple(self) -> tuple[float, float]:
        return (self.min, self.max)


@dataclass(frozen=True)
class ObjectRef:
    """One object-dictionary entry, ``index:subindex`` (written ``"0x2012:1"``)."""
    index: int
    subindex: int

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex}"


@dataclass(frozen=True)
class Device:
    """One CANopen node as the bus sees it.

    ``axes`` names the motor axes on the node in sub-index order (sub-index 1 = ``axes[0]``);
    ``joints`` are the robot-level names of those axes (what the simulator calls them).
    ``simulated_only`` marks nodes that exist only on a simulated robot (the test bench).
    ``eds`` is a shipped EDS file's name or an absolute path (``eds_path``).
    """
    name: str
    node_id: int
    eds: str
    axes: tuple[str, ...] = ()
    joints: tuple[str, ...] = ()
    simulated_only: bool = False
    profile: str = "ubot-board"

    @property
    def eds_path(self) -> Path:
        return eds_path(self.eds)


@dataclass(frozen=True)
class Bus:
    """The bus and its schedule: ``bitrate`` [bit/s], the SYNC period [ms] of the control loop,
    the agent's node-id (NMT master, SYNC producer), every node's producer heartbeat period and
    how long a drive tolerates the agent's silence before its safe state [ms]; the share of
    the bus the cyclic schedule may take [%] (the rest is for EMCY and SDO traffic)."""
    bitrate: int
    sync_period_ms: float
    agent_node_id: int
    heartbeat_period_ms: int
    consumer_heartbeat_ms: int
    load_budget_percent: float = 50.0

    @property
    def sync_period_s(self) -> float:
        return self.sync_period_ms / 1000.0

    @property
    def rate_hz(self) -> float:
        """SYNCs per second."""
        return 1000.0 / self.sync_period_ms


@dataclass(frozen=True)
class Node:
    """A drive node (one that carries axes): its name, node-id, profile and EDS."""
    name: str
    node_id: int
    profile: str
    eds: str


@dataclass(frozen=True)
class Axis:
    """One joint and the drive that moves it.

    Attributes:
        name: the joint (``elbow_left``). node / node_id / profile / eds: the node that carries
            it. subindex: its axis number on that node (1-based; the sub-index of the board's
            per-axis ARRAY objects; 1 on a one-axis CiA 402 node). label: its name on the node
            (``elbow``). mode: one of ``MODES[profile]``.
        gear: reduction (motor rad per joint rad, > 0). torque_constant: Kt [N m/A].
        back_emf: Ke [V s/rad] (None: not given). resistance: terminal resistance [ohm] (None:
            not given). encoder_counts: encoder increments per motor revolution (None: the drive
            reports SI units, as the uBot boards do).
        position_limits: joint range [rad] (None: turns without end, a wheel). velocity_limit
            [rad/s], torque_limit [N m] (joint side, <= Kt * gear * current_limit),
            current_limit [A]: what the host keeps to.
        stiffness_range [N m/rad], damping_range [N m s/rad]: the joint impedance the host may
            ask for (None: a torque-mode axis). stiffness_object / damping_object: the drive's
            objects that hold them (``0x2030:2`` on a board, ``0x2012:1``/``0x2012:2`` on a
            MAB MD style CiA 402 drive; None where the axis has no impedance).
    """
    name: str
    node: str
    node_id: int
    subindex: int
    label: str
    profile: str
    eds: str
    mode: str
    gear: float
    torque_constant: float
    back_emf: float | None
    resistance: float | None
    encoder_counts: int | None
    position_limits: Range | None
    velocity_limit: float
    torque_limit: float
    current_limit: float
    stiffness_range: Range | None
    damping_range: Range | None
    stiffness_object: ObjectRef | None
    damping_object: ObjectRef | None

    @property
    def impedance(self) -> bool:
        """The axis holds a joint impedance (stiffness and damping), not a bare torque."""
        return self.stiffness_range is not None


@dataclass(frozen=True)
class ImuNode:
    name: str
    node_id: int
    eds: str


@dataclass(frozen=True)
class BenchNode:
    """The simulator's test bench node (scenario, reset, ground truth): simulated robots only."""
    name: str
    node_id: int
    eds: str


@dataclass(frozen=True)
class RobotDescription:
    """A whole robot. ``source`` is the file it was read from."""
    name: str
    summary: str
    bus: Bus
    nodes: tuple[Node, ...]
    axes: tuple[Axis, ...]
    imu: ImuNode
    testbench: BenchNode | None
    source: str = ""

    @functools.cached_property
    def devices(self) -> tuple[Device, ...]:
        """Every node of the simulated robot (drives, IMU, test bench), in node-id order."""
        out = [Device(n.name, n.node_id, n.eds, tuple(a.label for a in self.node_axes(n.name)),
                      tuple(a.name for a in self.node_axes(n.name)), False, n.profile)
               for n in self.nodes]
        out.append(Device(self.imu.name, self.imu.node_id, self.imu.eds))
        if self.testbench is not None:
            out.append(Device(self.testbench.name, self.testbench.node_id, self.testbench.eds,
                              simulated_only=True))
        return tuple(sorted(out, key=lambda d: d.node_id))

    @functools.cached_property
    def robot_devices(self) -> tuple[Device, ...]:
        """The nodes a real robot has (no test bench)."""
        return tuple(d for d in self.devices if not d.simulated_only)

    def device(self, name_or_id: str | int) -> Device:
        """A node by name (``"arm_left"``) or node-id (KeyError if there is none)."""
        for d in self.devices:
            if d.name == name_or_id or d.node_id == name_or_id:
                return d
        raise KeyError(f"no device {name_or_id!r} on {self.name}; known: {[d.name for d in self.devices]}")

    def axis(self, name: str) -> Axis:
        """An axis by joint name (KeyError if there is none)."""
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(f"no axis {name!r} on {self.name}; known: {list(self.joints)}")

    def node_axes(self, node: str) -> tuple[Axis, ...]:
        """The axes of one drive node, in sub-index order."""
        return tuple(sorted((a for a in self.axes if a.node == node), key=lambda a: a.subindex))

    @property
    def joints(self) -> tuple[str, ...]:
        """Joint names in the order the description lists them."""
        return tuple(a.name for a in self.axes)

    @property
    def profiles(self) -> frozenset[str]:
        return frozenset(n.profile for n in self.nodes)
