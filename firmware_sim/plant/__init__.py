"""The uBot plant: MJCF model, physics accessors, motor constants, IMU, damage and falls."""
from .damage import CableSpec, ElbowCables, FallDetector
from .imu import Imu, ImuNoise, ImuSample
from .motors import MotorBank, MotorParams, read_motor_params
from .physics import AXES, IMPEDANCE_AXES, UBOT_XML, WHEEL_AXES, WHEEL_RADIUS, Physics, UnknownNameError

__all__ = [
    "AXES", "IMPEDANCE_AXES", "UBOT_XML", "WHEEL_AXES", "WHEEL_RADIUS", "Physics",
    "UnknownNameError", "MotorBank", "MotorParams", "read_motor_params", "Imu", "ImuNoise",
    "ImuSample", "CableSpec", "ElbowCables", "FallDetector",
]
