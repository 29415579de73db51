"""SDO abort codes (CiA 301 table 22) and the server-side value-range check.

``range_check`` is a write callback for canopen ``LocalNode.add_write_callback``: it decodes
the downloaded bytes with the object's data type and refuses values outside the EDS
``LowLimit``/``HighLimit`` before anything is stored (canopen runs write callbacks before it
stores, and an ``SdoAbortedError`` raised there becomes the abort frame).
"""
from __future__ import annotations

import enum

from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError


class AbortCode(enum.IntEnum):
    TOGGLE_BIT = 0x05030000
    TIMEOUT = 0x05040000
    UNSUPPORTED_ACCESS = 0x06010000
    WRITE_ONLY = 0x06010001           # attempt to read a write-only object
    READ_ONLY = 0x06010002            # attempt to write a read-only object
    NO_OBJECT = 0x06020000            # object does not exist in the dictionary
    NOT_MAPPABLE = 0x06040041
    TYPE_LENGTH = 0x06070010
    NO_SUBINDEX = 0x06090011
    VALUE_RANGE = 0x06090030          # value range of parameter exceeded
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    GENERAL = 0x08000000
    DEVICE_STATE = 0x08000022         # cannot be stored or used because of the device state
    NO_DATA = 0x08000024


RANGE_ABORTS = frozenset({AbortCode.VALUE_RANGE, AbortCode.VALUE_TOO_HIGH, AbortCode.VALUE_TOO_LOW})


def check_range(od: ODVariable, data: bytes) -> int | float | None:
    """Decode ``data`` for ``od`` and return the value, or raise ``SdoAbortedError`` with
    VALUE_TOO_HIGH / VALUE_TOO_LOW when it lies outside the EDS limits."""
    if od.min is None and od.max is None:
        return None
    value = od.decode_raw(data)
    if od.max is not None and value > od.max:
        raise SdoAbortedError(AbortCode.VALUE_TOO_HIGH)
    if od.min is not None and value < od.min:
        raise SdoAbortedError(AbortCode.VALUE_TOO_LOW)
    return value


def range_check(index: int, subindex: int, od: ODVariable, data: bytes) -> None:
    """LocalNode write callback enforcing the EDS value ranges."""
    check_range(od, data)
