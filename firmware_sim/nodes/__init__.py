"""CANopen nodes of the simulated robot."""
from firmware_sim.nodes.base import NodeApplication, SlaveNode, StaticApplication

__all__ = ["NodeApplication", "SlaveNode", "StaticApplication"]
