"""Motor-controller firmware: impedance/torque laws, splines, limits, faults, per-board API."""
from .boards import (
    BOARDS,
    DAMPING_RANGE,
    STIFFNESS_RANGE,
    AxisStatus,
    JointController,
    MotorController,
    WheelController,
)
from .errors import ConfigError, ConfigRangeError, ConfigStateError, UnknownAxisError
from .firmware import Firmware
from .spline import MAX_KNOTS, HermiteSpline

__all__ = [
    "BOARDS", "DAMPING_RANGE", "STIFFNESS_RANGE", "AxisStatus", "JointController",
    "MotorController", "WheelController", "ConfigError", "ConfigRangeError", "ConfigStateError",
    "UnknownAxisError", "Firmware", "MAX_KNOTS", "HermiteSpline",
]
