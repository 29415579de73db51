"""One episode, from request to result: reset, configure, SYNC loop with LQR, cost.

    runner = EpisodeRunner(bus)
    plan = runner.plan(request)          # pure: refuses (RequestRefused) before touching anything
    result = runner.run(plan)            # EpisodeResult, never raises for hardware faults

The runner knows no task: what theta means, how the robot is configured, the arm commands,
when the episode ends early and the cost terms are the task's (``ersac_hil.agent.tasks``),
looked up by the request's task name among ``EpisodeConfig.tasks`` (``UnknownTask``, reply
``unknown_task``, when this agent does not serve it). ``run``:

1. the cyclic nodes must be on the bus (``NodeMissing`` -> ``fault_simulator``);
2. reset: through the test-bench node when present (the task's scenario, seed, reset
   command), else wait for the go signal of a person who reset the robot (``go(timeout) -> bool``);
3. ``task.configure`` by SDO in PRE-OPERATIONAL, NMT start;
4. the SYNC loop (lock-step unless the bus is real-time): RPDOs with the LQR wheel torques
   and the task's arm commands (``task.begin`` after the first cycle), SYNC, TPDOs; ends after
   T = ``TASKS[task].horizon_s`` or when the task's end condition says so. ``task.begin`` may
   download by SDO (lifting: a spline of several kB, 5-10 ms): in lock-step the second SYNC
   waits for it, so an episode is the same whatever the machine; in real time it runs on a
   thread of its own while the SYNC loop keeps its period (the robot keeps balancing on the
   first commands) and its commands apply from the first cycle after it returned;
5. NMT pre-operational (the boards drop their torque), cost terms from the trace.

Safety (``agent.safety``, ``agent.limits``): a run refuses to start while the e-stop is
engaged; the pacing of each episode follows ``safety.pacing`` (lock-step only on a simulated
bench, refused elsewhere); an e-stop during the SYNC loop sends the quick-stop commands with the
next SYNC and ends the episode ``stopped`` (no cost terms: nothing is learnt from it); every
cyclic setpoint is clamped into ``EpisodeConfig.limits`` (counted as ``clamped_<setpoint>``)
and ``plan`` refuses a setup outside them.

A fault (PDO timeout, heartbeat lost, EMCY that is not a task outcome, bus down) ends the loop
at once; the result then carries the fault's status, the counters and the telemetry summary of
the cycles before it, and no cost terms at all (a cost never mixes valid and missing data).
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ersac_hil.agent import configure, costs
from ersac_hil.agent.bus import AgentBus, CycleTimes, EmcyEvent
from ersac_hil.agent.errors import AgentFault, BusFault, EmcyFault, HeartbeatLost
from ersac_hil.agent.limits import SetpointLimits
from ersac_hil.agent.lqr import BalanceController, BalanceDesign, LqrWeights, PendulumModel
from ersac_hil.agent.robot import UBOT, RobotParameters
from ersac_hil.agent.safety import BoardQuickStop, EstopEngaged, QuickStop, Safety, pacing
from ersac_hil.agent.tasks import EmcyMark, Task, default_tasks, lookup
from ersac_hil.agent.telemetry import Commands, Telemetry, Trace
from protocol.can.devices import TESTBENCH
from protocol.can.realtime import gc_paused
from protocol.can.objects import EmcyCode, Status
from protocol.zenoh import TASKS, EpisodeRequest, EpisodeResult

log = logging.getLogger(__name__)

OUTCOME_EMCY = {EmcyCode.CABLE_BROKEN: "hardware_damage", EmcyCode.OVER_CURRENT: "over_current",
                EmcyCode.FALLEN: "fallen", EmcyCode.BOTTLE_DROPPED: "bottle_dropped"}
"""EMCY codes that are task outcomes (failure flags), not faults."""
OUTCOME_STATUS = {Status.CABLE_BROKEN: "hardware_damage", Status.OVER_CURRENT: "over_current",
                  Status.FALLEN: "fallen", Status.BOTTLE_DROPPED: "bottle_dropped"}
_OUTCOME_BITS = int(sum(OUTCOME_STATUS))


@dataclass(frozen=True)
class EpisodeConfig:
    """What the agent does with a request (configuration, not code).

    Attributes:
        tasks: the tasks this agent serves, by name (default: every task of
            ``ersac_hil.agent.tasks`` with its default configuration).
        lqr: balance weights (the design point is each task's ``balance``).
        weights: per task, the cost weights of the reply's ``total_cost`` (default the
            contract's ``default_weights``; the learner re-weights the terms anyway).
        go_timeout_s: how long to wait for the go signal without a test bench.
        testbench_wait_s, testbench_recent_s: how long to listen for the test bench's heartbeat
            when not heard yet; how old its last heartbeat may be for it to count as present.
        node_timeout_s: how long the cyclic nodes may take to show up.
        robot: geometry and masses for the balance.
        limits: host-side limits of every setpoint and plan (``agent.limits``).
        quick_stop: what an e-stop sends (the drive profile's quick stop).
    """
    tasks: Mapping[str, Task] = field(default_factory=default_tasks)
    lqr: LqrWeights = LqrWeights()
    weights: Mapping[str, Mapping[str, float]] = field(
        default_factory=lambda: {name: dict(spec.default_weights) for name, spec in TASKS.items()})
    go_timeout_s: float = 600.0
    testbench_wait_s: float = 0.25
    testbench_recent_s: float = 5.0
    node_timeout_s: float = 1.0
    robot: RobotParameters = UBOT
    limits: SetpointLimits = field(default_factory=SetpointLimits.default)
    quick_stop: QuickStop = BoardQuickStop()

    def task(self, name: str) -> Task:
        """The served task called ``name`` (``UnknownTask`` if none)."""
        return lookup(self.tasks, name)


@dataclass(frozen=True)
class Plan:
    """A validated request and what it means for the robot.

    Attributes:
        request: the request as received.
        n_cycles: SYNC cycles of the full horizon.
        task: the task that serves it.
        setup: what ``task.plan(theta)`` made of theta (the task's own type).
    """
    request: EpisodeRequest
    n_cycles: int
    task: Task
    setup: Any


@dataclass
class _Episode:
    """Mutable record of one episode in progress (``run`` means a learning run elsewhere)."""
    samples: list[Telemetry] = field(default_factory=list)
    commands: list[Commands] = field(default_factory=list)  # sent (clamped) with each sample
    failures: dict[str, bool] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    status: str = "ok"
    detail: str = ""
    emcy: list[EmcyEvent] = field(default_factory=list)
    truth: dict[str, float] = field(default_factory=dict)
    times: CycleTimes = field(default_factory=CycleTimes)  # real time: SYNC jitter, host compute

    def count(self, name: str, n: int = 1) -> None:
        self.counts[name] = self.counts.get(name, 0) + n


class EpisodeRunner:
    """Runs episodes on an open ``AgentBus`` (one at a time; the caller serialises).

    ``observe``, if given, is called with each cycle's telemetry on the SYNC loop's thread right
    after the cycle (the ROS 2 bridge and the MCAP recorder hang on it): it must only hand the
    sample on, never block.
    """

    def __init__(self, bus: AgentBus, config: EpisodeConfig = EpisodeConfig(),
                 go: Callable[[float], bool] | None = None, safety: Safety | None = None,
                 observe: Callable[[Telemetry], None] | None = None) -> None:
        """``go(timeout) -> bool``: the go signal without a test bench (default: ``safety``'s,
        when given, else none: such an episode is aborted). ``safety``: the e-stop, go and
        pacing of the agent (default: no e-stop source, pacing ``auto``, or ``realtime`` if
        the bus was opened real-time)."""
        self.bus, self.config = bus, config
        self.safety = safety if safety is not None else Safety("realtime" if bus.timing.realtime else "auto")
        if go is None and safety is not None:
            go = lambda timeout: self.safety.wait_go(timeout, self.stop_requested)  # noqa: E731
        self.go = go
        self.observe = observe
        self.stop_requested = threading.Event()
        self._designs: dict[str, BalanceDesign] = {}
        self.last: LastEpisode | None = None

    # -- planning (pure) -------------------------------------------------------------------
    def plan(self, request: EpisodeRequest) -> Plan:
        """Validate ``request`` against the robot; ``RequestRefused`` if it must not run
        (``UnknownTask`` if this agent does not serve its task)."""
        task = self.config.task(request.task)
        n = int(round(task.spec.horizon_s / self.bus.timing.period_s))
        setup = task.plan(request.theta)
        self.config.limits.check_plan(setup)
        return Plan(request, n, task, setup)

    def design(self, task: str) -> BalanceDesign:
        """The LQR design of ``task`` (cached): the robot at the task's balance pose."""
        if task not in self._designs:
            cfg, balance = self.config, self.config.task(task).balance
            model = PendulumModel.from_robot(cfg.robot, balance.pose, balance.pose, balance.payload_kg)
            self._designs[task] = BalanceDesign.compute(model, self.bus.timing.period_s, cfg.lqr)
        return self._designs[task]

    # -- the episode ------------------------------------------------------------------------
    def run(self, plan: Plan) -> EpisodeResult:
        """Run ``plan``; hardware faults end up in the result's status, never as exceptions.
        ``RequestRefused`` (a spline from the measured start out of limits, a refused
        configuration) propagates: nothing moved."""
        request, task = plan.request, plan.task
        wall0 = time.monotonic()
        episode = _Episode()
        self.stop_requested.clear()
        bus = self.bus
        emcy_mark = bus.emcy_count
        started = testbench = False
        refusal = self.safety.refusal()
        if refusal is not None:
            raise EstopEngaged(refusal)
        try:
            bus.wait_for_nodes(timeout_s=self.config.node_timeout_s)
            try:  # what a node sent between episodes faults no episode
                bus.check_bus()
            except BusFault as exc:
                log.warning("between episodes: %s", exc)
            bus.nmt_preop()
            testbench = self._testbench_present()
            realtime = pacing(self.safety.pacing, bus.config, testbench)  # LockstepRefused: nothing moved
            if realtime != bus.timing.realtime:
                bus.timing = replace(bus.timing, realtime=realtime)
            if testbench:
                configure.reset_scenario(bus, task.scenario, request.seed)
            elif not self._wait_go():
                if self.safety.engaged is not None:
                    episode.status, episode.detail = "stopped", f"e-stop before the start: {self.safety.engaged}"
                else:
                    episode.status, episode.detail = "aborted", "no go signal: the robot was not reset"
                return self._result(plan, episode, wall0)
            emcy_mark = bus.emcy_count
            first = task.configure(bus, plan.setup)
            bus.nmt_start()
            started = True
            bus.enable_drives()
            with gc_paused():
                self._loop(plan, episode, first, emcy_mark)
        except AgentFault as exc:
            episode.status, episode.detail = exc.status, str(exc)
            episode.count(_fault_counter(exc))
        finally:
            if started:
                try:
                    bus.disable_drives()
                except AgentFault:
                    pass
                try:
                    bus.nmt_preop()
                except AgentFault:
                    pass
        if testbench and episode.status == "ok":
            try:  # best effort: ground truth for the summary
                truth, flags = configure.read_truth(bus)
                truth.update(task.ground_truth(bus, flags))
                episode.truth.update({k: v for k, v in truth.items() if math.isfinite(v)})
                bus.check_bus()  # a faulty node's answer to a readout: no ok episode of it
            except AgentFault as exc:
                episode.status, episode.detail = exc.status, str(exc)
                episode.count(_fault_counter(exc))
                episode.truth.clear()
        episode.emcy = bus.emcy_events(emcy_mark)
        return self._result(plan, episode, wall0)

    def _testbench_present(self) -> bool:
        """The test bench is on this bus: its heartbeat was heard within ``testbench_recent_s``
        (a loose window: a loaded machine may delay heartbeats, and mistaking a simulated robot
        for a real robot would wait for a go signal); if never heard yet, listen for one
        ``testbench_wait_s`` (the nodes' heartbeat timers are independent)."""
        deadline = time.monotonic() + self.config.testbench_wait_s
        while True:
            age = self.bus.heartbeat_ages().get(TESTBENCH.name)
            if age is not None and age < self.config.testbench_recent_s:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    def _wait_go(self) -> bool:
        if self.go is None:
            return False
        log.warning("no test bench: waiting for go (reset the robot, then 'ersac-hil go')")
        return bool(self.go(self.config.go_timeout_s))

    def _loop(self, plan: Plan, episode: _Episode, commands: Commands, emcy_mark: int) -> None:
        bus, task = self.bus, plan.task
        balance = task.balance
        ctl = BalanceController(self.design(task.name), self.config.robot, balance.payload_kg,
                                strike_acc=balance.strike_acc)
        end = task.end_condition(plan.setup, bus.timing.period_s)
        bus.reset_pacing()
        overruns0 = bus.overruns
        beginning: _BesideTheLoop | None = None
        estop, limits = self.safety.estop, self.config.limits
        try:
            observe = self.observe
            if estop.is_set():
                return self._quick_stop(episode, commands)
            sent = self._clamped(episode, commands)
            tel = bus.cycle(sent)
            ctl.start(tel)
            episode.samples.append(tel)
            episode.commands.append(sent)
            if observe is not None:
                observe(tel)
            if bus.timing.realtime:
                first, held = tel, commands
                beginning = _BesideTheLoop(lambda: task.begin(bus, plan.setup, first, held))
            else:
                commands = task.begin(bus, plan.setup, tel, commands)
            while len(episode.samples) < plan.n_cycles:
                if estop.is_set():
                    return self._quick_stop(episode, commands)
                if self.stop_requested.is_set():
                    episode.status, episode.detail = "aborted", "stopped on request"
                    return
                if beginning is not None and beginning.done():
                    commands, beginning = beginning.result(), None  # re-raises the task's error
                self._check_emcy(episode, emcy_mark)
                self._flags(episode, tel)
                ctl.payload = task.payload_kg(episode.failures)
                left, right = ctl.torque(tel)
                commands = Commands(wheel_torque=(left, right), torso_position=commands.torso_position,
                                    arm_left=commands.arm_left, arm_right=commands.arm_right,
                                    arm_control=commands.arm_control)
                sent = self._clamped(episode, commands, limits)
                tel = bus.cycle(sent)
                episode.samples.append(tel)
                episode.commands.append(sent)
                if observe is not None:
                    observe(tel)
                why = end(tel, len(episode.samples), episode.failures)
                if why is not None:
                    episode.detail = why
                    break
            bus.check_bus()  # a faulty node's frames after the last cycle: no ok episode of them
            self._check_emcy(episode, emcy_mark)
            self._flags(episode, tel)
        finally:
            if beginning is not None:  # never leave an SDO transfer running into the next episode
                beginning.settle()
            episode.count("late_cycles", bus.overruns - overruns0)
            episode.times = bus.times
            episode.count("saturated_cycles", ctl.saturated_cycles)
            if ctl.fallen:
                episode.failures["fallen"] = True
            if ctl.released_cycle is not None and episode.samples:
                episode.truth["balance_released_s"] = (ctl.released_cycle - episode.samples[0].cycle) * bus.timing.period_s

    def _clamped(self, episode: _Episode, commands: Commands, limits: SetpointLimits | None = None) -> Commands:
        """``commands`` inside the host-side limits; each clamp counted in the result."""
        inside, clamped = (limits or self.config.limits).clamp(commands)
        for name in clamped:
            episode.count(f"clamped_{name}")
        return inside

    def _quick_stop(self, episode: _Episode, last: Commands) -> None:
        """The e-stop's cycle: the profile's quick-stop commands with the next SYNC; the
        episode ends ``stopped`` (its samples so far stay in the summary, no cost terms)."""
        episode.status = "stopped"
        episode.detail = f"e-stop: {self.safety.engaged or 'engaged'}"
        episode.truth["estop_cycle"] = float(self.bus.cycles + 1)
        try:
            self.bus.cycle(self.config.quick_stop.stop_commands(last))
        except AgentFault as exc:  # sent or not, the run is stopped (NMT pre-operational follows)
            episode.detail += f"; the quick-stop cycle: {exc}"

    def _check_emcy(self, episode: _Episode, emcy_mark: int) -> None:
        events = self.bus.emcy_events(emcy_mark + len(episode.emcy))
        for ev in events:
            episode.emcy.append(ev)
            if ev.code == EmcyCode.NO_ERROR:
                continue
            flag = OUTCOME_EMCY.get(ev.code)  # type: ignore[call-overload]
            if flag is not None:
                episode.failures[flag] = True
            elif ev.code == EmcyCode.HEARTBEAT_LOST:
                raise HeartbeatLost(f"{ev.device} (lost the agent's heartbeat, EMCY 0x8130)", None,
                                    self.bus.timing.heartbeat_timeout_s)
            else:
                raise EmcyFault(f"EMCY 0x{ev.code:04X} from {ev.device} (register 0x{ev.register:02X})")

    @staticmethod
    def _flags(episode: _Episode, tel: Telemetry) -> None:
        status = tel.status_bits
        if status & _OUTCOME_BITS:
            for bit, flag in OUTCOME_STATUS.items():
                if status & bit:
                    episode.failures[flag] = True

    def _result(self, plan: Plan, episode: _Episode, wall0: float) -> EpisodeResult:
        request = plan.request
        period = self.bus.timing.period_s
        trace = Trace.from_samples(episode.samples, period)
        episode.count("emcy", len(episode.emcy))
        summary = costs.summary(trace, self.config.robot)
        summary.update(plan.task.summary(trace))
        if len(trace):
            lat = np.array([s.latency_s for s in episode.samples]) * 1000.0
            summary["sync_latency_p50_ms"] = float(np.percentile(lat, 50))
            summary["sync_latency_p99_ms"] = float(np.percentile(lat, 99))
            summary["sync_latency_max_ms"] = float(lat.max())
        for name, values in (("sync_jitter", episode.times.jitter_s), ("host_compute", episode.times.compute_s)):
            if values:  # real time only
                ms = np.array(values) * 1000.0
                summary[f"{name}_p50_ms"] = float(np.percentile(ms, 50))
                summary[f"{name}_p99_ms"] = float(np.percentile(ms, 99))
                summary[f"{name}_max_ms"] = float(ms.max())
        summary.update(episode.truth)
        terms: dict[str, float] = {}
        total = None
        if episode.status == "ok":
            first = episode.samples[0].cycle
            marks = [EmcyMark(ev.code, min(max(ev.cycle - first, 0), len(trace) - 1)) for ev in episode.emcy]
            terms = plan.task.cost_terms(trace, marks)
            if terms.get("damage"):
                episode.failures["hardware_damage"] = True
            total = TASKS[request.task].total_cost(terms, self.config.weights.get(request.task))
        failures = {flag: episode.failures.get(flag, False) for flag in
                    ("hardware_damage", "over_current", "fallen", "bottle_dropped")}
        first_cycle = episode.samples[0].cycle if episode.samples else 0
        self.last = LastEpisode(plan, tuple(episode.samples), tuple(episode.commands), tuple(
            (ev.code, ev.device, ev.cycle - first_cycle) for ev in episode.emcy))
        return EpisodeResult(
            episode_id=request.episode_id, task=request.task, status=episode.status,
            cost_terms=terms, total_cost=total, failures=failures,
            duration_s=len(trace) * period, wall_s=time.monotonic() - wall0,
            telemetry=summary, fault_counts=dict(episode.counts), detail=episode.detail[:4096])


@dataclass(frozen=True)
class LastEpisode:
    """What the runner kept of its latest episode (``agent.series`` writes it on request).

    Attributes:
        plan: the episode's plan.
        samples, commands: every cycle's telemetry and the commands sent with it.
        emcy: (code, device, cycle index from the first sample) of each EMCY of the episode.
    """
    plan: Plan
    samples: tuple[Telemetry, ...]
    commands: tuple[Commands, ...]
    emcy: tuple[tuple[int, str, int], ...]


def _fault_counter(exc: AgentFault) -> str:
    return {"fault_pdo_timeout": "pdo_timeouts", "fault_heartbeat": "heartbeat_lost",
            "fault_emcy": "emcy_faults"}.get(exc.status, "bus_faults")


class _BesideTheLoop:
    """``begin()`` on a thread of its own while the SYNC loop goes on (the thread inherits the
    loop's scheduling, SCHED_FIFO in real time)."""

    def __init__(self, begin: Callable[[], Commands]) -> None:
        self._commands: Commands | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(begin,), name="task-begin", daemon=True)
        self._thread.start()

    def _run(self, begin: Callable[[], Commands]) -> None:
        try:
            self._commands = begin()
        except BaseException as exc:  # noqa: BLE001 - handed to the SYNC loop's thread
            self._error = exc

    def done(self) -> bool:
        return not self._thread.is_alive()

    def result(self) -> Commands:
        """The commands ``begin`` returned (waits for it); raises what it raised."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._commands  # type: ignore[return-value]

    def settle(self) -> None:
        """Wait for a ``begin`` the loop left behind (a fault ended the loop first); its outcome
        no longer matters (its SDO transfers end within their timeout)."""
        self._thread.join()
