"""Typed configuration errors of the motor-controller firmware.

The CAN layer maps them to SDO abort codes:
- :class:`ConfigRangeError` -> 0x06090030 (value range of parameter exceeded);
- :class:`ConfigStateError` -> 0x08000022 (data cannot be transferred because of the present
  device state), e.g. starting a spline that was never loaded.
A refused setting changes nothing.
"""
from __future__ import annotations


class ConfigError(Exception):
    """Base class of refused firmware configurations."""


class ConfigRangeError(ConfigError, ValueError):
    """``value`` of parameter ``name`` is outside [low, high]."""

    def __init__(self, name: str, value: float, low: float, high: float) -> None:
        self.name, self.value, self.low, self.high = name, value, low, high
        super().__init__(f"{name} = {value!r} outside [{low}, {high}]")


class ConfigStateError(ConfigError, RuntimeError):
    """The command is not possible in the controller's present state."""


class UnknownAxisError(ConfigError, KeyError):
    """An axis or controller name this board / simulator does not have."""

    def __str__(self) -> str:  # KeyError would print the repr of the message
        return str(self.args[0]) if self.args else "unknown axis"
