"""The agent's CiA 402 drive profile: one standard servo drive per axis (a robot description whose
nodes have the ``cia402`` profile), driven through python canopen's ``BaseNode402``.

``Cia402Bus`` is an ``AgentBus`` (NMT, heartbeats, EMCY, SDO, the SYNC cycle are the same)
with its own drive layer: the episode code and the tasks call the same methods on either.

* enable (``enable_drives``, after NMT start): every drive's mode set through ``BaseNode402``
  (``op_mode``, refused unless 0x6502 lists it, then confirmed by reading 0x6061 back), its CSP
  target set to where the axis is, then the power state machine to OPERATION ENABLED
  (from FAULT through a fault reset); disable (``disable_drives``) to SWITCH ON DISABLED;
  ``quick_stop`` sends the quick-stop command to every drive at once (the e-stop).
* commands (``Cia402Encoder``): each SYNC one RPDO per drive with its target position and
  target torque. Wheels (mode ``cst``): the LQR's torque. Impedance axes in ``csp-impedance``:
  the position setpoint, followed by the drive's own impedance (stiffness and damping written
  to the objects the description names, ``apply_impedance``); in ``cst``: the impedance law on
  the host, tau = K (q* - q) + D (qd* - qd) from the last cycle's telemetry. Lifting's spline
  is evaluated on the host (``download_spline`` keeps it; the commands' START_SPLINE rising
  edge starts it) and streamed as setpoints, one per SYNC, each the spline's value at the end
  of its period. Commands without ENABLE in a control word (the e-stop's cycle,
  ``agent.safety.BoardQuickStop``) send the quick stop to every drive before that cycle's SYNC.
* telemetry (``Cia402Decoder``): position (0x6064), velocity (0x606C), current (0x6078) from
  the drives' TPDOs, scaled by the description (gear, encoder increments, rated current); the
  motor voltage V = I R + Ke G qdot from the description's constants (the drives report the DC
  link, not the winding voltage); the IMU as on the board robot; each board-shaped status word
  (``Telemetry.status``) the OR of its drives' states as ``Status`` bits (OPERATION_ENABLED,
  FAULT). The task outcomes come by EMCY as on the boards.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence

import numpy as np

import canopen
from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ersac_hil.agent.bus import AgentBus, BusTiming, _sdo_errors
from ersac_hil.agent.errors import ConfigRefused, DriveFault
from ersac_hil.agent.policies import ArmImpedance, Spline
from ersac_hil.agent.telemetry import IMU_SCALES, JOINTS, Commands, Telemetry
from protocol.can import cia402
from protocol.can.busconfig import BusConfig
from protocol.can.cia402 import DriveScaling, Index, State
from protocol.can.devices import object_dictionary
from protocol.can.objects import Control, Status
from protocol.can.objects import Index as BoardIndex
from protocol.can.pdo import PdoSpec, pdo_maps, pdo_struct
from protocol.can.sdo import AbortCode
from protocol.robot import Axis, RobotDescription

log = logging.getLogger(__name__)

MODES = {"csp-impedance": "CYCLIC SYNCHRONOUS POSITION", "cst": "CYCLIC SYNCHRONOUS TORQUE"}
"""The description's modes as ``BaseNode402`` names them."""
_ARM_JOINTS = {"left": ("shoulder_left", "elbow_left"), "right": ("shoulder_right", "elbow_right")}


def scaling(axis: Axis) -> DriveScaling:
    """The profile units of ``axis``'s drive as the description gives them (rated current = the
    axis's current limit, rated torque = Kt times it, at the motor)."""
    if axis.encoder_counts is None:
        raise ValueError(f"axis {axis.name}: a CiA 402 drive needs encoder_counts")
    return DriveScaling(axis.gear, float(axis.encoder_counts), axis.current_limit,
                        axis.torque_constant * axis.current_limit)


class Cia402Encoder:
    """``Commands`` -> one RPDO (target position, target torque) per drive each SYNC.

    Args:
        bus: for the cycle count and the last telemetry (host impedance law, spline time).
        rpdos: per drive in sending order: (joint, COB-ID, struct) of its synchronous RPDO.
    """

    def __init__(self, bus: "Cia402Bus", rpdos: Sequence[tuple[str, int, object]]) -> None:
        self.bus, self.rpdos = bus, tuple(rpdos)
        self._start: dict[str, int] = {}
        self._control = Control(0)
        self._stopped = False

    def reset(self) -> None:
        """A new episode: no spline running, no quick stop."""
        self._start.clear()
        self._control = Control(0)
        self._stopped = False

    def _references(self, commands: Commands) -> dict[str, tuple[float, float]]:
        """(position, velocity) reference of every impedance joint this cycle."""
        bus, cycle = self.bus, self.bus.cycles
        rising = commands.arm_control & ~self._control
        self._control = commands.arm_control
        refs = {"torso": (commands.torso_position, 0.0)}
        for side, pose in (("left", commands.arm_left), ("right", commands.arm_right)):
            table = bus.splines.get(side)
            if table is not None and rising & Control.START_SPLINE:
                self._start[side] = cycle
            start = self._start.get(side)
            if table is None or start is None:
                refs.update(zip(_ARM_JOINTS[side], ((q, 0.0) for q in pose)))
                continue
            refs.update(zip(_ARM_JOINTS[side], table[min(cycle - start, len(table) - 1)]))
        return refs

    def encode(self, commands: Commands) -> list[tuple[int, bytes]]:
        bus = self.bus
        if not commands.control & Control.ENABLE or not commands.arm_control & Control.ENABLE:
            if not self._stopped:  # the boards' "disable" (the e-stop's commands): quick stop
                self._stopped = True
                bus.quick_stop()
        refs = self._references(commands)
        last = bus.last_telemetry
        wheels = dict(zip(("wheel_left", "wheel_right"), commands.wheel_torque))
        frames = []
        for joint, cob_id, layout in self.rpdos:
            axis, s = bus.axes[joint], bus.scalings[joint]
            if joint in wheels:
                position, torque = 0, s.per_mille_of_torque(wheels[joint])
            else:
                q_ref, qd_ref = refs[joint]
                position, torque = s.increments_of(q_ref), 0
                if axis.mode == "cst":  # the impedance law on the host
                    k, d = bus.host_gains[joint]
                    j = JOINTS.index(joint)
                    q, qd = (last.position[j], last.velocity[j]) if last is not None else (q_ref, 0.0)
                    torque = s.per_mille_of_torque(k * (q_ref - q) + d * (qd_ref - qd))
            frames.append((cob_id, layout.pack(position, torque)))  # type: ignore[attr-defined]
        return frames


class Cia402Decoder:
    """The TPDO frames of one SYNC -> ``Telemetry`` (see the module docstring)."""

    def __init__(self, bus: "Cia402Bus", tpdos: Sequence[PdoSpec]) -> None:
        self.bus = bus
        self._frames = [(p.cob_id, pdo_struct(p).unpack_from, p.keys, p.device) for p in tpdos]
        joint_of = {d.name: d.joints[0] for d in bus.drives}
        self._joint_of = joint_of
        self._imu = bus.description.imu.name
        self._groups = bus.layout.status_nodes
        electrical = []
        for joint in JOINTS:
            a = bus.axes[joint]
            electrical.append((a.resistance or 0.0, (a.back_emf or 0.0) * a.gear))
        self._electrical = electrical

    def decode(self, cycle: int, frames: Mapping[int, bytes | bytearray], latency_s: float = 0.0) -> Telemetry:
        bus = self.bus
        values: dict[str, dict[tuple[int, int], int]] = {}
        for cob_id, unpack, keys, device in self._frames:
            values.setdefault(device, {}).update(zip(keys, unpack(frames[cob_id])))
        position, velocity, current, voltage = [], [], [], []
        words: dict[str, int] = {}
        for node, joint in self._joint_of.items():
            state = State.of(values[node][(Index.STATUSWORD, 0)])
            words[node] = ((int(Status.OPERATION_ENABLED) if state is State.OPERATION_ENABLED else 0)
                           | (int(Status.FAULT) if state in (State.FAULT, State.FAULT_REACTION_ACTIVE) else 0))
        for joint, (r, ke_g) in zip(JOINTS, self._electrical):
            v, s = values[bus.node_of[joint]], bus.scalings[joint]
            qd, i = s.velocity(v[(Index.VELOCITY_ACTUAL, 0)]), s.current(v[(Index.CURRENT_ACTUAL, 0)])
            position.append(s.position(v[(Index.POSITION_ACTUAL, 0)]))
            velocity.append(qd)
            current.append(i)
            voltage.append(i * r + ke_g * qd)
        imu = values[self._imu]
        words[self._imu] = int(imu[(BoardIndex.STATUS, 0)])
        status = []
        for group in self._groups:
            word = 0
            for name in group:
                word |= words[name]
            status.append(word)
        pitch = [IMU_SCALES[i].from_raw(imu[(i, 0)]) for i in (
            BoardIndex.PITCH, BoardIndex.PITCH_RATE, BoardIndex.PITCH_ACCELERATION,
            BoardIndex.ACCELERATION_X, BoardIndex.ACCELERATION_Z)]
        tel = Telemetry(cycle, tuple(position), tuple(velocity), tuple(current), tuple(voltage),
                        *pitch, tuple(status), latency_s)
        bus.last_telemetry = tel
        return tel


class Cia402Bus(AgentBus):
    """The CANopen master of a robot on CiA 402 drives (``description``: its nodes and axes)."""

    def __init__(self, config: BusConfig, description: RobotDescription, timing: BusTiming = BusTiming()) -> None:
        self.drives = tuple(d for d in description.devices if d.profile == "cia402")
        if tuple(sorted(j for d in self.drives for j in d.joints)) != tuple(sorted(JOINTS)):
            raise ValueError(f"{description.name}: CiA 402 drives for {sorted(JOINTS)} expected")
        self.axes = {a.name: a for a in description.axes}
        self.node_of = {d.joints[0]: d.name for d in self.drives}
        self.scalings = {a.name: scaling(a) for a in description.axes}
        self.host_gains: dict[str, tuple[float, float]] = {
            j: (50000 * cia402.KP_FACTOR, 5000 * cia402.KD_FACTOR) for j in self.axes}
        """Stiffness and damping of the host's impedance law (axes in ``cst``), the drives'
        own defaults until ``apply_impedance``."""
        self.splines: dict[str, list[tuple[tuple[float, float], ...]]] = {}
        """Per arm, the downloaded spline's (position, velocity) of each joint at the end of
        every SYNC period from its start."""
        self.last_telemetry: Telemetry | None = None
        super().__init__(config, timing=timing, description=description)

    # -- AgentBus hooks --------------------------------------------------------------------
    def _node(self, dev) -> canopen.RemoteNode:  # noqa: ANN001
        if dev in self.drives:
            return BaseNode402(dev.node_id, object_dictionary(dev))
        return super()._node(dev)

    def _setup(self, node: canopen.RemoteNode) -> None:
        if not isinstance(node, BaseNode402):
            return
        node.setup_402_state_machine(read_pdos=False)  # PDO maps from the EDS
        for tpdo in node.tpdo.values():
            if tpdo.enabled and tpdo.trans_type in (254, 255):
                tpdo.add_callback(_event_driven)
        if not self.timing.realtime:  # a stalled simulator answers late (``AgentBus``)
            patience = self.timing.lockstep_patience_s
            node.TIMEOUT_SWITCH_STATE_SINGLE = node.TIMEOUT_SWITCH_STATE_FINAL = patience
            node.TIMEOUT_SWITCH_OP_MODE = patience

    def _command_encoder(self, rpdos: list) -> Cia402Encoder:
        out = []
        for d in self.drives:
            for p in pdo_maps(d):
                if p.direction == "rpdo" and p.synchronous and p.entries:
                    if p.keys != ((Index.TARGET_POSITION, 0), (Index.TARGET_TORQUE, 0)):
                        raise ValueError(f"{d.name}: RPDO {p.number} maps {p.keys}, not target position "
                                         "and target torque")
                    out.append((d.joints[0], p.cob_id, pdo_struct(p)))
        return Cia402Encoder(self, out)

    def _telemetry_decoder(self) -> Cia402Decoder:
        return Cia402Decoder(self, tuple(self._tpdo_specs.values()))

    # -- the drive layer -------------------------------------------------------------------
    def _drive(self, joint: str) -> BaseNode402:
        return self.nodes[self.node_of[joint]]  # type: ignore[return-value]

    def apply_impedance(self, impedance: ArmImpedance) -> None:
        """Arm stiffness and damping: into the drive's objects (``csp-impedance``, SDO) or the
        host's law (``cst``); outside the description's range refused (``ConfigRefused``)."""
        for side in ("left", "right"):
            for joint, k, d in zip(_ARM_JOINTS[side], impedance.stiffness, impedance.damping):
                axis = self.axes[joint]
                for value, allowed in ((k, axis.stiffness_range), (d, axis.damping_range)):
                    if allowed is not None and value not in allowed:
                        raise ConfigRefused(self.node_of[joint], 0, 0, value, AbortCode.VALUE_RANGE)
                if axis.mode == "cst":
                    self.host_gains[joint] = (float(k), float(d))
                    continue
                for ref, value, factor in ((axis.stiffness_object, k, cia402.KP_FACTOR),
                                           (axis.damping_object, d, cia402.KD_FACTOR)):
                    self.write(self.node_of[joint], ref.index, ref.subindex, round(value / factor))

    def download_spline(self, side: str, spline: Spline) -> None:
        """Kept on the host, sampled once at the end of every SYNC period from its start (the
        last sample holds: the spline's end at rest); streamed once START_SPLINE rises."""
        period = self.timing.period_s
        n = int(math.ceil(spline.duration / period)) + 1
        q, qd = spline.sample((np.arange(n) + 1) * period)
        self.splines[side] = [tuple(zip(qj, qdj)) for qj, qdj in zip(q.tolist(), qd.tolist())]

    def enable_drives(self) -> None:
        """Modes set and confirmed, CSP targets where the axes are, OPERATION ENABLED."""
        self.last_telemetry = None
        self._encoder.reset()  # type: ignore[union-attr]
        for joint in JOINTS:
            node, axis, name = self._drive(joint), self.axes[joint], self.node_of[joint]
            mode = MODES[axis.mode]
            try:
                # the statusword and mode as they are now (the event-driven TPDO1 that NMT
                # start made the drive send may not be here yet)
                node.tpdo_values[Index.STATUSWORD] = node.sdo[Index.STATUSWORD].raw
                node.tpdo_values[Index.MODES_DISPLAY] = node.sdo[Index.MODES_DISPLAY].raw
                if not node.is_op_mode_supported(mode):
                    raise DriveFault(f"{name}: 0x6502 does not list {mode.lower()}")
                if node.state in ("FAULT", "FAULT REACTION ACTIVE"):
                    self._reset_fault(name, node)
                if node.state != "SWITCH ON DISABLED":
                    node.state = "SWITCH ON DISABLED"
                node.op_mode = mode  # logs its own timeouts: the read-back decides
                if node.op_mode != mode:
                    raise DriveFault(f"{name}: mode of operation {node.op_mode.lower()}, not {mode.lower()}")
                if axis.mode == "csp-impedance":
                    with _sdo_errors(name, Index.TARGET_POSITION, 0, None):
                        node.sdo[Index.TARGET_POSITION].raw = node.sdo[Index.POSITION_ACTUAL].raw
                node.state = "OPERATION ENABLED"
            except (RuntimeError, ValueError) as exc:  # BaseNode402's timeouts and refusals
                raise DriveFault(f"{name}: {exc}") from exc
            except (SdoAbortedError, SdoCommunicationError) as exc:
                raise DriveFault(f"{name}: SDO {exc}") from exc

    @staticmethod
    def _reset_fault(name: str, node: BaseNode402) -> None:
        """``BaseNode402.reset_from_fault`` (it waits out its own timeout, a known FIXME, then
        walks to OPERATION ENABLED); a drive still in FAULT is a ``DriveFault`` naming its error
        code (0x603F), e.g. a broken cable's 0xFF10, which no reset clears."""
        try:
            node.reset_from_fault()
        except RuntimeError:  # its transitions timed out: the statusword says why below
            pass
        if node.is_faulted():
            with _sdo_errors(name, Index.ERROR_CODE, 0, None):
                code = int(node.sdo[Index.ERROR_CODE].raw)
            raise DriveFault(f"{name}: still in FAULT after a fault reset (error code 0x{code:04X}, 0x603F)")

    def disable_drives(self) -> None:
        """Every drive to SWITCH ON DISABLED (torque off)."""
        self.splines.clear()
        failed = []
        for joint in JOINTS:
            node = self._drive(joint)
            try:
                if node.state not in ("SWITCH ON DISABLED", "FAULT"):
                    node.state = "SWITCH ON DISABLED"
            except (RuntimeError, ValueError, SdoCommunicationError) as exc:
                failed.append(f"{self.node_of[joint]}: {exc}")
        if failed:
            raise DriveFault("; ".join(failed))

    def quick_stop(self) -> None:
        """The quick-stop command to every drive at once (their event-driven RPDO: taken on
        arrival, no SYNC needed); what each does is its 0x605A."""
        for joint in JOINTS:
            self._drive(joint).controlword = cia402.Command.QUICK_STOP.bits

    def drive_states(self) -> dict[str, str]:
        """Each drive's power state as its last statusword shows it."""
        return {self.node_of[j]: self._drive(j).state for j in JOINTS}


def _event_driven(pdo_map) -> None:  # noqa: ANN001 - canopen's PdoMap
    """canopen takes a TPDO that arrived twice for a periodic one (``PdoMap.period``) and then
    waits up to 0.2 s for its next frame before every statusword or mode read; an event-driven
    TPDO comes when its values change: read its cached values instead (``BaseNode402`` keeps
    them fresh from every frame; its statusword checks fall back to SDO)."""
    pdo_map.period = None


def agent_bus(config: BusConfig, description: RobotDescription, timing: BusTiming = BusTiming()) -> AgentBus:
    """The agent's bus for ``description``: ``Cia402Bus`` when its drives are CiA 402, else the
    board robot's ``AgentBus`` (its nodes from the description)."""
    if "cia402" in description.profiles:
        return Cia402Bus(config, description, timing)
    return AgentBus(config, timing=timing, description=description)
