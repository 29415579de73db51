"""``--ros2 [--ros-domain N] [--ros-namespace NS] [--ros-decimation K]`` and ``--record DIR``
(light: no rosbags, no mcap until a feed starts)."""
from __future__ import annotations

import argparse
from dataclasses import dataclass

from ersac_hil.cli_args import UsageError
from ersac_hil.ros2 import names

PART = ".part"
"""Suffix of an MCAP file of ``--record DIR`` still being written (``recorder``; renamed when whole)."""


@dataclass(frozen=True)
class Ros2Options:
    """``agent --ros2 [--ros-domain N] [--ros-namespace NS] [--ros-decimation K]``.

    Attributes:
        domain: ROS_DOMAIN_ID (0..232). namespace: ROS namespace, ``None``: ``/<robot>``.
        decimation: publish joint states and IMU every K-th SYNC cycle (1: every cycle).
        node: the ROS node name. queue_size: samples the publisher thread may lag behind the
            control loop before it drops (and counts) the newest.
    """
    domain: int = 0
    namespace: str | None = None
    decimation: int = 1
    node: str = "ersac_agent"
    queue_size: int = 16384

    def __post_init__(self) -> None:
        names.check_domain(self.domain)
        if self.namespace is not None:
            names.check_namespace(self.namespace)
        if self.decimation < 1:
            raise names.RosNameError(f"--ros-decimation must be >= 1, got {self.decimation}")

    def namespace_for(self, robot: str) -> str:
        """The namespace, by default ``/<robot>`` (characters a ROS name lacks as ``_``)."""
        return self.namespace if self.namespace is not None else names.robot_namespace(robot)


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("ROS 2 and MCAP (docs/ros2.md)")
    g.add_argument("--ros2", action="store_true",
                   help="publish joint states, IMU, diagnostics and episodes for ROS 2 (rmw_zenoh key space)")
    g.add_argument("--ros-domain", dest="ros_domain", type=int, default=0, help="ROS_DOMAIN_ID (default 0)")
    g.add_argument("--ros-namespace", dest="ros_namespace", default=None,
                   help="ROS namespace (default /<robot>)")
    g.add_argument("--ros-decimation", dest="ros_decimation", type=int, default=1,
                   help="publish joint states and IMU every K-th cycle (default 1: every SYNC)")
    g.add_argument("--record", metavar="DIR", default=None,
                   help="write each episode as DIR/<episode_id>.mcap (ROS 2 profile)")


def from_args(args: argparse.Namespace) -> Ros2Options | None:
    """The options of ``--ros2`` (None without it); ``UsageError`` naming a bad value."""
    try:
        options = Ros2Options(args.ros_domain, args.ros_namespace, args.ros_decimation)
    except names.RosNameError as exc:
        raise UsageError(str(exc)) from None
    return options if args.ros2 else None
