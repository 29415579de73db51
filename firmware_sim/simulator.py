"""The firmware simulator's facade: physics plant + motor-controller firmware + scenario,
stepped one control period at a time. No CAN in here; the CANopen nodes call this API.

    sim = Simulator(control_period=0.005, substeps=5)
    sim.reset("bracing", seed=3)
    sim.set_impedance("elbow_left", 250.0, 5.0)
    events = sim.step()                 # exactly one control period of physics
    sim.axis("wheel_left").current      # A
    sim.imu().pitch                     # rad

Units: SI (rad, rad/s, N m, A, V, s, m, N s). Axis names: ``AXES``. Board names: ``BOARDS``.
Determinism: the same scenario, seed and command sequence give bit-identical telemetry.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import mujoco
import numpy as np

from protocol.can.devices import SYNC_PERIOD_S

from .controllers import (
    BOARDS,
    ConfigStateError,
    Firmware,
    HermiteSpline,
    JointController,
    MotorController,
    UnknownAxisError,
    WheelController,
)
from .plant import (
    AXES,
    CableSpec,
    ElbowCables,
    FallDetector,
    Imu,
    ImuNoise,
    ImuSample,
    MotorBank,
    MotorParams,
    Physics,
    read_motor_params,
)
from .plant.damage import ELBOWS, SIDES
from .plant.overrides import PhysicsOverrides
from .scenarios import SCENARIOS, Scenario, make

MAX_TIMESTEP = 0.001
"""s, coarsest physics timestep accepted."""

_BOARD_OF_AXIS = {axis: board for board, axes in BOARDS.items() for axis in axes}


@dataclass(frozen=True)
class AxisState:
    """Telemetry of one axis: position (rad), velocity (rad/s) at the end of the period;
    motor current (A) and terminal voltage (V) of the period's last physics substep."""

    position: float
    velocity: float
    current: float
    voltage: float


class FailureKind(str, Enum):
    OVER_CURRENT = "over_current"
    CABLE_BROKEN = "cable_broken"
    FALLEN = "fallen"
    BOTTLE_DROPPED = "bottle_dropped"


@dataclass(frozen=True)
class FailureEvent:
    """A failure that happened during the last step (reported once).

    ``axis``/``board`` name the affected axis and board where there is one
    (over-current: that axis; cable broken: the elbow and its arm board).
    """

    kind: FailureKind
    sim_time: float
    axis: str | None = None
    board: str | None = None


@dataclass(frozen=True)
class Status:
    """Latched failure flags of the episode."""

    over_current: bool
    over_current_axes: tuple[str, ...]
    cable_broken_left: bool
    cable_broken_right: bool
    fallen: bool
    bottle_dropped: bool


@dataclass(frozen=True)
class GroundTruth:
    """Bench readouts for tests (not available to the robot-side agent over its own sensors).

    cable tensions (N, now and episode peak), bottle height of the shell centre and the
    shell+liquid centre of mass (m, NaN without a bottle), the drawn impact momentum (N s,
    NaN outside bracing) and launch time (s, NaN before), noise-free IMU values, the drawn
    breaking tensions of this episode's elbow cables (N), the bottle's liquid mass (kg, NaN
    without a bottle).
    """

    scenario: str
    seed: int
    sim_time: float
    impact_momentum: float
    impact_time: float
    cable_tension_left: float
    cable_tension_right: float
    peak_cable_tension_left: float
    peak_cable_tension_right: float
    bottle_height: float
    bottle_com: tuple[float, float, float]
    fallen: bool
    damaged: bool
    bottle_dropped: bool
    pitch: float
    pitch_rate: float
    pitch_acc: float
    base_x: float
    cable_strength_left: float = float("nan")
    cable_strength_right: float = float("nan")
    liquid_mass: float = float("nan")


class _Rig:
    """Everything compiled for one scenario; reused across resets of that scenario."""

    def __init__(self, scenario: Scenario, timestep: float, control_period: float,
                 imu_noise: ImuNoise, cable: CableSpec, overrides: PhysicsOverrides) -> None:
        spec = scenario.build_spec()
        overrides.apply_spec(spec)
        overrides.apply_scenario(scenario)
        spec.option.timestep = timestep
        self.scenario = scenario
        self.physics = Physics.from_spec(spec)
        scenario.prepare(self.physics)
        self.physics.reset()
        self.physics.forward()
        self.motors = MotorBank(read_motor_params(self.physics.model))
        self.firmware = Firmware(self.physics, self.motors)
        self.imu = Imu(self.physics, control_period, imu_noise)
        self.cables = ElbowCables(self.physics, self.motors.gear, cable)
        self.falls = FallDetector(self.physics)


class Simulator:
    """Lock-step simulator of the uBot's motor controllers, IMU and test bench.

    Args:
        control_period: s per :meth:`step` (the SYNC period; default the robot description's, 5 ms).
        substeps: physics steps per control period; the timestep control_period / substeps
            must be at most 1 ms.
        balance_free: wheels passive (their drivers ignore torque commands), kept over resets.
        imu_noise: noise standard deviations of the IMU.
        cable: elbow cable constants (median breaking tension, strength scatter).
        physics: named overrides of the plant (``plant.overrides``; its cable entries
            replace those of ``cable``); empty: the model as it is.
    """

    def __init__(self, control_period: float = SYNC_PERIOD_S, substeps: int = 5, *,
                 balance_free: bool = False, imu_noise: ImuNoise = ImuNoise(),
                 cable: CableSpec = CableSpec(), physics: PhysicsOverrides = PhysicsOverrides()) -> None:
        if not (control_period > 0 and substeps >= 1):
            raise ValueError("control_period must be > 0 and substeps >= 1")
        if control_period / substeps > MAX_TIMESTEP * (1 + 1e-9):
            raise ValueError(f"timestep {control_period / substeps} s exceeds {MAX_TIMESTEP} s")
        self.control_period = float(control_period)
        self.substeps = int(substeps)
        self.timestep = self.control_period / self.substeps
        self._imu_noise = imu_noise
        self._overrides = physics
        self._cable = physics.cable(cable)
        self._balance_free = bool(balance_free)
        self._rigs: dict[str, _Rig] = {}
        self._rig: _Rig | None = None
        self._seed = 0
        self._events: tuple[FailureEvent, ...] = ()
        self._current = [0.0] * 7
        self._voltage = [0.0] * 7
        self._boards: dict[str, MotorController] = {}
        self._drives: dict[str, MotorController] = {}

    # ---- episode --------------------------------------------------------------------------
    @property
    def scenarios(self) -> tuple[str, ...]:
        return tuple(SCENARIOS)

    def reset(self, scenario: str = "idle", seed: int = 0) -> None:
        """Start an episode of ``scenario`` (``"idle"``, ``"bracing"``, ``"lifting"``) with the
        random quantities (impact momentum, IMU noise) drawn from ``seed``. All boards return
        to power-on defaults (enabled, default impedance, holding the initial pose)."""
        if not (isinstance(seed, (int, np.integer)) and seed >= 0):
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        rig = self._rigs.get(scenario)
        if rig is None:
            rig = _Rig(make(scenario), self.timestep, self.control_period, self._imu_noise,
                       self._cable, self._overrides)
            self._rigs[scenario] = rig
        self._rig, self._seed = rig, int(seed)
        # streams: scenario, IMU noise, cable strengths, load (spawn(4)[:3] == spawn(3): adding
        # a stream leaves the earlier draws of every seed unchanged)
        scenario_rng, imu_rng, cable_rng, load_rng = (np.random.default_rng(s)
                                                      for s in np.random.SeedSequence(int(seed)).spawn(4))
        phys = rig.physics
        rig.cables.reset(cable_rng)                # restores the model fields it edits
        rig.scenario.vary(phys, load_rng)
        phys.reset()
        rig.scenario.initialize_episode(phys, scenario_rng)
        rig.firmware.reset()
        phys.forward()
        rig.falls.reset()
        rig.imu.reset(imu_rng)
        if not self._boards:
            fw = rig.firmware
            self._boards = {"wheels": WheelController(fw),
                            **{b: JointController(b, fw) for b in BOARDS if b != "wheels"}}
        for board in (*self._boards.values(), *self._drives.values()):
            board.bind(rig.firmware)
        self.balance_free = self._balance_free
        self._events = ()
        self._snapshot_electrical()

    def _require(self) -> _Rig:
        if self._rig is None:
            raise ConfigStateError("call reset(scenario, seed) first")
        return self._rig

    def step(self) -> tuple[FailureEvent, ...]:
        """Advance exactly one control period (``substeps`` physics steps, the firmware running
        at every substep). Returns the failures that happened in this period (each once)."""
        rig = self._require()
        phys, fw, scen, cables = rig.physics, rig.firmware, rig.scenario, rig.cables
        m, d = phys.model, phys.data
        force = d.actuator_force
        events: list[FailureEvent] = []
        step1, step2 = mujoco.mj_step1, mujoco.mj_step2
        write_controls, monitor, update_cables = fw.write_controls, fw.monitor, cables.update
        check_scenario = scen.checks_substeps
        scen.before_step(phys)
        last = self.substeps - 1
        for k in range(self.substeps):
            write_controls()
            step2(m, d)
            over = monitor()
            snapped = update_cables(force)
            if check_scenario and scen.after_substep(phys):
                events.append(FailureEvent(FailureKind.BOTTLE_DROPPED, d.time))
            if over or snapped:
                self._substep_failures(over, snapped, d.time, events)
            if k == last:
                self._snapshot_electrical()
            step1(m, d)
        rig.imu.sample()
        if rig.falls.update(rig.imu.true_pitch):
            events.append(FailureEvent(FailureKind.FALLEN, d.time))
        self._events = tuple(events)
        return self._events

    def _substep_failures(self, over: tuple[int, ...], snapped: tuple[int, ...], t: float,
                          events: list[FailureEvent]) -> None:
        fw = self._require().firmware
        for i in over:
            events.append(FailureEvent(FailureKind.OVER_CURRENT, t, AXES[i], _BOARD_OF_AXIS[AXES[i]]))
        for side in snapped:
            axis, board = ELBOWS[side], f"arm_{SIDES[side]}"
            fw.disconnect(AXES.index(axis))
            # the arm board's fault reaction: a lost transmission stops the whole arm (safe
            # state, zero torque on shoulder and elbow), so the arm goes limp
            self._boards[board].enter_safe_state("elbow cable broken")
            events.append(FailureEvent(FailureKind.CABLE_BROKEN, t, axis, board))

    def _snapshot_electrical(self) -> None:
        """Motor currents/voltages of the substep just integrated (forces and speeds at the
        same state)."""
        rig = self._require()
        d, act = rig.physics.data, rig.physics.axes.actuator_view
        self._current = rig.motors.current(d.actuator_force[act].tolist())
        self._voltage = rig.motors.voltage(self._current, d.actuator_velocity[act].tolist())

    # ---- readouts -------------------------------------------------------------------------
    @property
    def sim_time(self) -> float:
        """s since reset."""
        return self._require().physics.time

    @property
    def scenario(self) -> str:
        return self._require().scenario.name

    @property
    def seed(self) -> int:
        return self._seed

    @property
    def physics(self) -> Physics:
        """The underlying physics (tests, linearisation); do not step it directly."""
        return self._require().physics

    def axis(self, name: str) -> AxisState:
        rig = self._require()
        try:
            i = AXES.index(name)
        except ValueError:
            raise UnknownAxisError(f"unknown axis {name!r}; axes are {AXES}") from None
        d, idx = rig.physics.data, rig.physics.axes
        return AxisState(float(d.qpos[idx.qpos[i]]), float(d.qvel[idx.dof[i]]), self._current[i], self._voltage[i])

    def axis_values(self) -> list[float]:
        """Position, velocity, current and voltage of every axis (the same values as
        :meth:`axis`, for the telemetry hot path): 28 floats, shape (4, 7) row-major, columns
        ``AXES``."""
        rig = self._require()
        d, idx = rig.physics.data, rig.physics.axes
        return [*d.qpos[idx.qpos_view].tolist(), *d.qvel[idx.dof_view].tolist(), *self._current, *self._voltage]

    def axis_flags(self) -> np.ndarray:
        """The boards' state flags of every axis, shape (8, 7) bool: rows in ``AxisStatus``
        field order, columns ``AXES`` (what :meth:`MotorController.board_status` ORs per board)."""
        return self._require().firmware.flags()

    def axes(self) -> dict[str, AxisState]:
        """All seven axes, in ``AXES`` order."""
        return {name: self.axis(name) for name in AXES}

    def imu(self) -> ImuSample:
        """The IMU reading taken at the end of the last period (noisy)."""
        return self._require().imu.latest

    @property
    def events(self) -> tuple[FailureEvent, ...]:
        """Failures of the last step (same as its return value)."""
        return self._events

    @property
    def fallen(self) -> bool:
        """The fall detector has latched (``status.fallen``, without building the status)."""
        return self._require().falls.fallen

    @property
    def status(self) -> Status:
        rig = self._require()
        fw, broken = rig.firmware, rig.cables.broken
        oc = tuple(a for a, f in zip(AXES, fw.over_current) if f)
        return Status(over_current=bool(oc), over_current_axes=oc,
                      cable_broken_left=bool(broken[0]), cable_broken_right=bool(broken[1]),
                      fallen=rig.falls.fallen, bottle_dropped=rig.scenario.bottle_dropped)

    @property
    def truth(self) -> GroundTruth:
        rig = self._require()
        phys, scen, cables, imu = rig.physics, rig.scenario, rig.cables, rig.imu.truth
        com = scen.bottle_com(phys)
        return GroundTruth(
            scenario=scen.name, seed=self._seed, sim_time=phys.time,
            impact_momentum=scen.impact_momentum, impact_time=scen.impact_time,
            cable_tension_left=float(cables.tension[0]), cable_tension_right=float(cables.tension[1]),
            peak_cable_tension_left=float(cables.peak[0]), peak_cable_tension_right=float(cables.peak[1]),
            bottle_height=scen.bottle_height(phys), bottle_com=(float(com[0]), float(com[1]), float(com[2])),
            fallen=rig.falls.fallen, damaged=bool(cables.broken.any()),
            bottle_dropped=scen.bottle_dropped, pitch=imu.pitch, pitch_rate=imu.pitch_rate,
            pitch_acc=imu.pitch_acc, base_x=float(phys.data.xpos[phys.base_id][0]),
            cable_strength_left=float(cables.strength[0]), cable_strength_right=float(cables.strength[1]),
            liquid_mass=scen.liquid_mass)

    # ---- boards ---------------------------------------------------------------------------
    def controller(self, name: str) -> MotorController:
        """The board ``name`` (``"wheels"``, ``"torso"``, ``"arm_left"``, ``"arm_right"``); the
        same object for the simulator's whole life."""
        self._require()
        try:
            return self._boards[name]
        except KeyError:
            raise UnknownAxisError(f"unknown board {name!r}; boards are {tuple(BOARDS)}") from None

    def motor(self, axis: str) -> MotorParams:
        """Motor and gearbox constants of ``axis`` (as compiled from the model)."""
        return self._require().motors.params[axis]

    def axis_controller(self, axis: str) -> MotorController:
        """The controller of one axis alone (a one-axis drive: ``WheelController`` of a wheel,
        ``JointController`` of an impedance axis), the same object for the simulator's whole
        life; it shares the firmware with the boards."""
        self._require()
        drive = self._drives.get(axis)
        if drive is None:
            board = _BOARD_OF_AXIS.get(axis)
            if board is None:
                raise UnknownAxisError(f"unknown axis {axis!r}; axes are {AXES}")
            fw = self._require().firmware
            drive = (WheelController(fw, (axis,)) if board == "wheels"
                     else JointController(board, fw, (axis,)))
            self._drives[axis] = drive
        return drive

    def _joint_board(self, axis: str) -> JointController:
        board = _BOARD_OF_AXIS.get(axis)
        if board is None or board == "wheels":
            raise UnknownAxisError(f"{axis!r} is not an impedance axis; those are {AXES[2:]}")
        return self.controller(board)  # type: ignore[return-value]

    # ---- commands -------------------------------------------------------------------------
    @property
    def balance_free(self) -> bool:
        return self._balance_free

    @balance_free.setter
    def balance_free(self, free: bool) -> None:
        self._balance_free = bool(free)
        if self._rig is not None:
            self.controller("wheels").balance_free = self._balance_free  # type: ignore[attr-defined]

    def set_wheel_torque(self, left: float, right: float) -> None:
        """Wheel torques (N m, joint side, positive drives forward), until changed."""
        self.controller("wheels").set_torque(left, right)  # type: ignore[attr-defined]

    def set_setpoint(self, axis: str, q: float) -> None:
        """Fixed position setpoint (rad) of an impedance axis; cancels its spline."""
        self._joint_board(axis).set_setpoint(axis, q)

    def set_impedance(self, axis: str, stiffness: float, damping: float) -> None:
        """Joint stiffness (N m/rad, 0..500) and damping (N m s/rad, 0..50)."""
        self._joint_board(axis).set_impedance(axis, stiffness, damping)

    def load_spline(self, target: str, times: Sequence[float], positions, velocities) -> HermiteSpline:
        """Store a cubic Hermite spline on a board (``"arm_left"``, ``"arm_right"``,
        ``"torso"``: positions/velocities shape (n_knots, n_axes of the board)) or on one axis
        (positions/velocities shape (n_knots,)). Times in s from the start command."""
        if target in BOARDS and target != "wheels":
            board = self.controller(target)
            return board.load_spline(times, positions, velocities)  # type: ignore[attr-defined]
        return self._joint_board(target).load_spline(times, positions, velocities, axes=(target,))

    def start_spline(self, *targets: str) -> None:
        """Start the stored splines of the given boards/axes (all loaded ones if none given)
        at the next physics substep."""
        names = targets or tuple(b for b in BOARDS if b != "wheels"
                                 and self.controller(b).spline is not None)  # type: ignore[attr-defined]
        boards = []
        for t in names:
            board = self.controller(t) if t in BOARDS else self._joint_board(t)
            if not isinstance(board, JointController):
                raise UnknownAxisError(f"{t!r} has no spline")
            boards.append(board)
        for board in dict.fromkeys(boards):
            board.start_spline()

    def trigger_impact(self) -> None:
        """Bracing: launch the pendulum now (if not launched yet)."""
        rig = self._require()
        rig.scenario.trigger_impact(rig.physics)
