"""The CAN side of the contract: CANopen (CiA 301) devices of the uBot bench.

* ``bench``     - devices, node-ids, EDS files (``BENCH``, ``object_dictionary``)
* ``cobid``     - COB-ID assignment (pre-defined connection set) and its inverse
* ``objects``   - object indexes, scaling, status/control bits, EMCY codes
* ``pdo``       - PDO maps as read from the EDS files
* ``busload``   - worst-case bus load of the cyclic schedule
* ``sdo``       - abort codes and the server-side value-range check
* ``busconfig`` - ``BusConfig`` and ``open_bus``: how either side reaches the bus
"""
from protocol.can.bench import AGENT_NODE_ID, BENCH, ROBOT, Device, device, object_dictionary
from protocol.can.busconfig import BusConfig, BusConfigError, open_bus, resolve_bus_config

__all__ = ["AGENT_NODE_ID", "BENCH", "ROBOT", "BusConfig", "BusConfigError", "Device", "device",
           "object_dictionary", "open_bus", "resolve_bus_config"]
