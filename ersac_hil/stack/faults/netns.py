"""Two network namespaces joined by a veth pair, for the faults of the network between the
daemon and the robot (needs root)."""
from __future__ import annotations

import os
import subprocess
import uuid

__all__ = ["Netns", "netns_unavailable"]


def netns_unavailable() -> str | None:
    """Why the test cannot make network namespaces here, or ``None``."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    name = f"ersac-probe-{uuid.uuid4().hex[:8]}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "delete", name], capture_output=True)
    return None


class Netns:
    """Two network namespaces joined by a veth pair, made here and deleted by :meth:`close`:
    ``daemon`` (address ``DAEMON_IP``) and ``robot`` (``ROBOT_IP``), loopback up in both. Only
    these two addresses, inside the two namespaces; nothing in the machine's own namespace."""

    DAEMON_IP = "10.199.0.1"
    ROBOT_IP = "10.199.0.2"

    def __init__(self) -> None:
        tag = uuid.uuid4().hex[:8]
        self.daemon, self.robot = f"ersac-d-{tag}", f"ersac-r-{tag}"
        self._ends = {"daemon": f"vd{tag}", "robot": f"vr{tag}"}
        self._made: list[str] = []
        try:
            for ns in (self.daemon, self.robot):
                self._ip("netns", "add", ns)
                self._made.append(ns)
            self._ip("link", "add", self._ends["daemon"], "netns", self.daemon, "type", "veth", "peer", "name",
                     self._ends["robot"], "netns", self.robot)
            for ns, dev, ip in ((self.daemon, self._ends["daemon"], self.DAEMON_IP),
                                (self.robot, self._ends["robot"], self.ROBOT_IP)):
                self._ip("-n", ns, "addr", "add", f"{ip}/30", "dev", dev)
                self._ip("-n", ns, "link", "set", dev, "up")
                self._ip("-n", ns, "link", "set", "lo", "up")
        except Exception:
            self.close()
            raise

    @staticmethod
    def _ip(*args: str) -> None:
        done = subprocess.run(["ip", *args], capture_output=True, text=True)
        if done.returncode != 0:
            raise OSError(f"ip {' '.join(args)}: {done.stderr.strip()}")

    def prefix(self, ns: str) -> list[str]:
        """The argv prefix running a command inside ``ns`` (``ip netns exec`` execs it: same pid)."""
        return ["ip", "netns", "exec", ns]

    def link(self, up: bool, side: str = "daemon") -> None:
        """``side``'s end of the veth (``daemon`` or ``robot``) up or down: a partition
        between the two namespaces, as seen first by that side."""
        ns = self.daemon if side == "daemon" else self.robot
        self._ip("-n", ns, "link", "set", self._ends[side], "up" if up else "down")

    def close(self) -> None:
        for ns in reversed(self._made):  # deleting a namespace deletes its veth end and the peer
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        self._made = []
