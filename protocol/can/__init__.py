"""The CAN side of the contract: the CANopen (CiA 301) devices of the uBot and the simulator's
test bench.

* ``devices``   - devices, node-ids, EDS files (``DEVICES``, ``ROBOT``, ``object_dictionary``)
* ``nmt``       - NMT states by name
* ``cobid``     - COB-ID assignment (pre-defined connection set) and its inverse
* ``objects``   - object indexes, scaling, status/control bits, EMCY codes
* ``pdo``       - PDO maps as read from the EDS files
* ``busload``   - worst-case bus load of the cyclic schedule
* ``sdo``       - abort codes and the server-side value-range check
* ``busconfig`` - ``BusConfig`` and ``open_bus``: how either side reaches the bus
"""
from protocol.can.devices import AGENT_NODE_ID, DEVICES, ROBOT, Device, device, object_dictionary
from protocol.can.busconfig import BusConfig, BusConfigError, open_bus, resolve_bus_config

__all__ = ["AGENT_NODE_ID", "DEVICES", "ROBOT", "BusConfig", "BusConfigError", "Device", "device",
           "object_dictionary", "open_bus", "resolve_bus_config"]
