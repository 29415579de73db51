"""The agent's telemetry and episodes as ROS 2 Jazzy messages (rosbags' typestore: the message
classes, their CDR and RIHS01 type hashes; nothing here encodes by hand).

Topics, relative to the node's namespace (``/ubot1`` by default):

=================  =================================  =============================================
topic              type                               what
=================  =================================  =============================================
``joint_states``   ``sensor_msgs/msg/JointState``     every joint (``JOINTS`` order): position [rad],
                                                      velocity [rad/s], effort [N m] (motor current
                                                      x torque constant x gear of the robot
                                                      description's axis; NaN without one)
``imu``            ``sensor_msgs/msg/Imu``            body pitch as orientation (rotation about +y,
                                                      x forward, z up), pitch rate as angular
                                                      velocity y [rad/s], acceleration x/z [m/s^2];
                                                      covariances 0 (unknown)
``diagnostics``    ``diagnostic_msgs/msg/             per device its status word (level, set bits),
                   DiagnosticArray``                  EMCY frames and the episode's fault; on change
``episode``        ``diagnostic_msgs/msg/             per episode: id, task, theta, status, cost and
                   DiagnosticStatus``                 cost terms, failures as key/value pairs
=================  =================================  =============================================
"""
from __future__ import annotations

import functools
import math
import struct
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ersac_hil.agent.bus import EmcyEvent
from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Telemetry
from protocol.can.fastpath import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE
from protocol.can.objects import EmcyCode, Status
from protocol.robot import RobotDescription, default_description
from protocol.zenoh import EpisodeRequest, EpisodeResult

JOINT_STATE = "sensor_msgs/msg/JointState"
IMU = "sensor_msgs/msg/Imu"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
STATUS = "diagnostic_msgs/msg/DiagnosticStatus"
TOPICS: dict[str, str] = {"joint_states": JOINT_STATE, "imu": IMU, "diagnostics": DIAGNOSTICS,
                          "episode": STATUS}
UPDATES = "learner/updates"
"""The topic of the learner's updates in ``report --mcap`` exports (``DiagnosticStatus``)."""
"""Relative topic name -> ROS 2 type of everything the robot publishes."""

CAN_FRAME = "can_msgs/msg/Frame"
LOG = "foxglove_msgs/msg/Log"
RECORDED: dict[str, str] = {"can": CAN_FRAME, "events": LOG}
"""Topics of the MCAP files only: every CAN frame of the episode, and its events (start, EMCY,
faults, end) as Foxglove's ``foxglove.Log`` in its ROS 2 form."""
_EXTRA_TYPES = {
    # the CAN frame of ros2_socketcan / ros2_canopen (not in the Jazzy core typestore)
    CAN_FRAME: "std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\n"
               "uint8 dlc\nuint8[8] data\n",
    # foxglove_msgs/msg/Log, the ROS 2 definition of foxglove.Log
    LOG: "uint8 UNKNOWN=0\nuint8 DEBUG=1\nuint8 INFO=2\nuint8 WARNING=3\nuint8 ERROR=4\nuint8 FATAL=5\n"
         "builtin_interfaces/Time timestamp\nuint8 level\nstring message\nstring name\nstring file\nuint32 line\n",
}
LOG_INFO, LOG_WARN, LOG_ERROR = 2, 3, 4

OK, WARN, ERROR = 0, 1, 2  # DiagnosticStatus levels
_ERROR_BITS = Status.FAULT | Status.OVER_CURRENT | Status.CABLE_BROKEN | Status.SAFE_STATE
_WARN_BITS = Status.FALLEN | Status.BOTTLE_DROPPED | Status.CURRENT_LIMITING | Status.POSITION_LIMIT


@functools.cache
def typestore() -> Any:
    """rosbags' ROS 2 Jazzy typestore, with the two types of the MCAP files that Jazzy's core
    set lacks (``RECORDED``)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for name, text in _EXTRA_TYPES.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def type_hash(typename: str) -> str:
    """``RIHS01_<hex>`` of a type (REP-2016), from rosbags."""
    return typestore().hash_rihs01(typename)


def msgdef(typename: str) -> str:
    """The ``ros2msg`` schema text of a type (MCAP's ROS 2 profile)."""
    return typestore().generate_msgdef(typename, ros_version=2)[0]


def serialize(message: Any, typename: str) -> bytes:
    """CDR (little endian, with its 4-byte encapsulation header)."""
    return bytes(typestore().serialize_cdr(message, typename))


def deserialize(data: bytes, typename: str) -> Any:
    return typestore().deserialize_cdr(data, typename)


@functools.cache
def _t(name: str) -> Any:
    """The message class of ``name`` (the typestore builds its ``types`` table per access)."""
    return typestore().types[name]


def header(stamp_ns: int, frame_id: str = "") -> Any:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return _t("std_msgs/msg/Header")(_t("builtin_interfaces/msg/Time")(sec, nsec), frame_id)


def torque_per_amp(description: RobotDescription | None = None) -> np.ndarray:
    """Joint torque per motor ampere, ``JOINTS`` order: torque constant x gear of each axis of
    the robot description (default: the default description); NaN for a joint it has no axis of."""
    d = description if description is not None else default_description()
    axes = {a.name: a for a in d.axes}
    return np.array([axes[j].torque_constant * axes[j].gear if j in axes else math.nan for j in JOINTS],
                    dtype=np.float64)


def joint_state(tel: Telemetry, stamp_ns: int, per_amp: np.ndarray) -> Any:
    return _joint_state(stamp_ns, tel.position, tel.velocity, np.array(tel.current, dtype=np.float64) * per_amp)


def _joint_state(stamp_ns: int, position: Sequence[float], velocity: Sequence[float],
                 effort: Sequence[float]) -> Any:
    return _t(JOINT_STATE)(header(stamp_ns, "base_link"), list(JOINTS), np.array(position, dtype=np.float64),
                           np.array(velocity, dtype=np.float64), np.array(effort, dtype=np.float64))


def imu(tel: Telemetry, stamp_ns: int) -> Any:
    return _imu(stamp_ns, *_imu_fields(tel))


def _imu_fields(tel: Telemetry) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """Orientation (a pitch about y), angular velocity and linear acceleration of ``tel``."""
    half = tel.pitch / 2.0
    return (0.0, math.sin(half), 0.0, math.cos(half)), (0.0, tel.pitch_rate, 0.0), (tel.acc_x, 0.0, tel.acc_z)


def _imu(stamp_ns: int, orientation: Sequence[float], angular_velocity: Sequence[float],
         linear_acceleration: Sequence[float]) -> Any:
    v3, zeros = _t("geometry_msgs/msg/Vector3"), np.zeros(9, dtype=np.float64)
    return _t(IMU)(header(stamp_ns, "imu_link"), _t("geometry_msgs/msg/Quaternion")(*orientation), zeros,
                   v3(*angular_velocity), zeros, v3(*linear_acceleration), zeros)


# -- the per-cycle messages' CDR, fast: rosbags' bytes of one message, its numbers patched ----------
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec
_MARK_STAMP = 0x51A3B7C9 * 1_000_000_000 + 0x2F1E4D3C
"""A stamp whose two fields (sec, nanosec) are unlike anything else in the messages."""


class CdrTemplate:
    """The CDR of one shape of a message type (``serialize``'s bytes, from rosbags), with the
    offsets where rosbags put its stamp and its float64 fields: ``pack`` copies the bytes and
    writes the values there, and is ``serialize`` of the same message to the bit (a test holds
    them equal for drawn messages). The offsets are found in rosbags' own output: ``build``
    makes the message from a stamp and float fields, and is serialized once with marker values
    in every field, each field's markers found exactly once.

    Args:
        typename: the ROS 2 type. build: ``(stamp_ns, *fields) -> message`` (rosbags' class).
        sizes: the number of float64 values of each field (the shape).
    """

    def __init__(self, typename: str, build: Any, sizes: Sequence[int]) -> None:
        marks, k = [], 1
        for n in sizes:
            marks.append(tuple(1000.0 + (k + i) / 7919.0 for i in range(n)))
            k += n
        self.data = serialize(build(_MARK_STAMP, *marks), typename)
        self.stamp_at = self._find(_STAMP.pack(*divmod(_MARK_STAMP, 1_000_000_000)))
        self.fields = tuple((struct.Struct(f"<{len(v)}d"), self._find(struct.pack(f"<{len(v)}d", *v))) for v in marks)

    def _find(self, marker: bytes) -> int:
        at = self.data.find(marker)
        if at < 0 or self.data.find(marker, at + 1) >= 0:
            raise ValueError("a field's markers are not once, contiguous, in rosbags' CDR of the template")
        return at

    def pack(self, stamp_ns: int, *fields: Sequence[float]) -> bytes:
        """The CDR of the message ``build(stamp_ns, *fields)``; each field of its template's size."""
        buf = bytearray(self.data)
        _STAMP.pack_into(buf, self.stamp_at, *divmod(stamp_ns, 1_000_000_000))
        for (packer, at), values in zip(self.fields, fields):
            packer.pack_into(buf, at, *values)
        return bytes(buf)


@functools.cache
def _joint_state_template() -> CdrTemplate:
    return CdrTemplate(JOINT_STATE, _joint_state, (len(JOINTS),) * 3)


@functools.cache
def _imu_template() -> CdrTemplate:
    return CdrTemplate(IMU, _imu, (4, 3, 3))


def joint_state_cdr(tel: Telemetry, stamp_ns: int, per_amp: Sequence[float]) -> bytes:
    """``serialize(joint_state(tel, stamp_ns, per_amp), JOINT_STATE)``, from the template of
    ``len(JOINTS)`` joints (rosbags serializes any other shape)."""
    n = len(JOINTS)
    if not len(tel.position) == len(tel.velocity) == len(tel.current) == len(per_amp) == n:
        return serialize(joint_state(tel, stamp_ns, np.asarray(per_amp, dtype=np.float64)), JOINT_STATE)
    return _joint_state_template().pack(stamp_ns, tel.position, tel.velocity,
                                        [c * k for c, k in zip(tel.current, per_amp)])


def imu_cdr(tel: Telemetry, stamp_ns: int) -> bytes:
    """``serialize(imu(tel, stamp_ns), IMU)``, from its template."""
    return _imu_template().pack(stamp_ns, *_imu_fields(tel))


def _kv(pairs: Iterable[tuple[str, object]]) -> list:
    kv = _t("diagnostic_msgs/msg/KeyValue")
    return [kv(k, str(v)) for k, v in pairs]


def _status(level: int, name: str, message: str, hardware_id: str, values: Iterable[tuple[str, object]]) -> Any:
    return _t(STATUS)(level, name, message, hardware_id, _kv(values))


def status_level(word: int) -> int:
    return ERROR if word & _ERROR_BITS else WARN if word & _WARN_BITS else OK


def device_statuses(robot: str, tel: Telemetry) -> list:
    """One DiagnosticStatus per device of the status words."""
    out = []
    for device, word in zip(STATUS_DEVICES, tel.status):
        bits = [b.name for b in Status if word & b]
        out.append(_status(status_level(word), f"{robot}/{device}", ", ".join(bits) or "ok", device,
                           [("status_word", f"0x{word:04X}"), ("cycle", tel.cycle)]))
    return out


def emcy_status(robot: str, ev: EmcyEvent) -> Any:
    try:
        name = EmcyCode(ev.code).name
    except ValueError:
        name = f"0x{ev.code:04X}"
    level = OK if ev.code == EmcyCode.NO_ERROR else ERROR
    return _status(level, f"{robot}/emcy", f"EMCY {name} from {ev.device}", ev.device,
                   [("code", f"0x{ev.code:04X}"), ("register", f"0x{ev.register:02X}"),
                    ("data", ev.data.hex()), ("cycle", ev.cycle)])


def diagnostics(stamp_ns: int, statuses: Sequence[Any]) -> Any:
    return _t(DIAGNOSTICS)(header(stamp_ns), list(statuses))


def episode_status(robot: str, request: EpisodeRequest, result: EpisodeResult | None,
                   fault: str = "") -> Any:
    """The per-episode message: name ``<robot>/episode``, hardware_id the episode id; values
    ``task``, ``seed``, ``theta_<i>``, then (when finished) ``status``, ``total_cost``,
    ``cost.<term>``, ``failure.<flag>``, ``duration_s``, ``trace``; message the status.
    Level OK for an ``ok`` episode without failures, WARN with failures, ERROR otherwise."""
    values: list[tuple[str, object]] = [("task", request.task), ("seed", request.seed)]
    values += [(f"theta_{i}", repr(float(x))) for i, x in enumerate(request.theta)]
    if result is None:  # started, or (``fault``) ended without the agent's result
        return _status(ERROR if fault else OK, f"{robot}/episode", fault or "started", request.episode_id,
                       values + ([("status", fault)] if fault else []))
    values += [("status", result.status),
               ("total_cost", "" if result.total_cost is None else repr(float(result.total_cost)))]
    values += [(f"cost.{k}", repr(float(v))) for k, v in sorted(result.cost_terms.items())]
    values += [(f"failure.{k}", str(v).lower()) for k, v in sorted(result.failures.items())]
    values += [("duration_s", repr(float(result.duration_s))), ("trace", result.trace)]
    level = ERROR if not result.ok else WARN if any(result.failures.values()) else OK
    return _status(level, f"{robot}/episode", fault or result.status, request.episode_id, values)


def fault_status(robot: str, result: EpisodeResult) -> Any:
    """The episode's fault (a result that is not ``ok``) as a diagnostic."""
    counts = sorted((k, v) for k, v in result.fault_counts.items() if v)
    return _status(ERROR, f"{robot}/fault", result.detail or result.status, result.episode_id,
                   [("status", result.status)] + counts)


def can_frame(stamp_ns: int, arbitration_id: int, flags: int, dlc: int, data: bytes) -> Any:
    """A ``can_msgs/msg/Frame`` (``flags``: ``protocol.can.fastpath`` bits; data zero-padded to 8)."""
    payload = np.zeros(8, dtype=np.uint8)
    payload[:min(len(data), 8)] = np.frombuffer(bytes(data[:8]), dtype=np.uint8)
    return _t(CAN_FRAME)(header(stamp_ns, CAN_FRAME_ID), arbitration_id, bool(flags & FLAG_REMOTE),
                         bool(flags & FLAG_EXTENDED), bool(flags & FLAG_ERROR), dlc, payload)


CAN_FRAME_ID = "can"
_CAN_CDR = struct.Struct("<4siII4sI???B8s")  # CDR header, Header (stamp, frame_id 'can'), id, flags, dlc, data


def can_frame_cdr(stamp_ns: int, arbitration_id: int, flags: int, dlc: int, data: bytes) -> bytes:
    """``serialize(can_frame(...), CAN_FRAME)``, packed with one struct (``can_frames_cdr``)."""
    return can_frames_cdr(stamp_ns, [(arbitration_id, flags, dlc, data)])[0]


def can_frames_cdr(stamp_ns: int, frames: list) -> list[bytes]:
    """``serialize(can_frame(...), CAN_FRAME)`` of each frame of one burst (``AgentBus.tap``), all
    stamped ``stamp_ns``: ``(COB-ID, data)`` pairs (standard data frames) or ``(id, flags, dlc,
    data)``. Packed with one struct a frame: an episode has ~18 frames a cycle, and rosbags'
    serializer takes ~50-100 us a frame with the message built. The layout is rosbags' (a test
    holds it byte for byte to ``serialize`` for any frame)."""
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    pack, head, frame_id = _CAN_CDR.pack, b"\x00\x01\x00\x00", b"can\x00"
    return [pack(head, sec, nsec, 4, frame_id, f[0], False, False, False, len(f[1]), bytes(f[1][:8])) if len(f) == 2
            else pack(head, sec, nsec, 4, frame_id, f[0], bool(f[1] & FLAG_REMOTE), bool(f[1] & FLAG_EXTENDED),
                      bool(f[1] & FLAG_ERROR), f[2], bytes(f[3][:8]))
            for f in frames]


def log(stamp_ns: int, level: int, message: str, name: str) -> Any:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return _t(LOG)(_t("builtin_interfaces/msg/Time")(sec, nsec), level, message, name, "", 0)


def warm_up() -> None:
    """What each type costs once, done before the first episode: rosbags compiles a type's
    serializer at its first message (milliseconds a type), the templates of the per-cycle
    messages are made from rosbags' CDR, the schemas generated. The feed process does it before
    it says it is ready, so that its first episode does not carry it."""
    _joint_state_template(), _imu_template()
    status = _status(OK, "warm-up", "", "", [("key", "value")])
    serialize(status, STATUS)
    serialize(diagnostics(0, [status]), DIAGNOSTICS)
    serialize(log(0, LOG_INFO, "", ""), LOG)
    for typename in {**TOPICS, **RECORDED}.values():
        msgdef(typename)


def update_status(robot: str, update: Any) -> Any:
    """A learner update (``ersac_hil.daemon.store.UpdateRecord``) as a DiagnosticStatus: name
    ``<robot>/learner/update``, hardware_id the run, message ``update <idx>``; values ``idx``,
    ``theta_before_<i>``, ``theta_after_<i>``, ``cost``, ``J``, ``r``, ``r_z``, ``td_error``
    (empty during warm-up), ``kappa``, ``lr``, ``episodes``."""
    def num(x: float | None) -> str:
        return "" if x is None else repr(float(x))
    values: list[tuple[str, object]] = [("idx", update.idx)]
    values += [(f"theta_before_{i}", num(x)) for i, x in enumerate(update.theta_before)]
    values += [(f"theta_after_{i}", num(x)) for i, x in enumerate(update.theta_after)]
    values += [(k, num(getattr(update, k))) for k in ("cost", "J", "r", "r_z", "td_error", "kappa", "lr")]
    values.append(("episodes", " ".join(update.episodes or (update.episode_id,))))
    return _status(OK, f"{robot}/learner/update", f"update {update.idx}", update.run_id, values)
