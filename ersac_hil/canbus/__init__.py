"""CAN bus plumbing on the agent's side: the loopback hub and backend discovery."""
from ersac_hil.canbus.backends import available_backends, vcan_status
from ersac_hil.canbus.hub import LoopbackHub

__all__ = ["LoopbackHub", "available_backends", "vcan_status"]
