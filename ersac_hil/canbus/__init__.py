"""CAN bus plumbing on the agent's side: the loopback hub and backend discovery."""
import can.interfaces

from ersac_hil.canbus.backends import available_backends, vcan_status
from ersac_hil.canbus.hub import LoopbackHub

# python-can finds both through this package's ``can.interface`` entry points; an editable
# install made before an entry point was added lacks it until reinstalled, so those who import
# this package get it anyway
can.interfaces.BACKENDS.setdefault("zenoh", ("ersac_hil.canbus.zenoh_bus", "ZenohBus"))
can.interfaces.BACKENDS.setdefault("ipc", ("ersac_hil.canbus.ipc", "IpcBus"))

__all__ = ["LoopbackHub", "available_backends", "vcan_status"]
