"""The agent process: a Zenoh front end on the episode runner.

* liveliness token ``<prefix>/<robot>/agent/alive`` while the agent is up, and
  ``.../agent/session/<zid>`` naming its session (the learner accepts replies from it only);
* queryable ``<prefix>/<robot>/episode/run``: ``EpisodeRequest`` -> ``EpisodeResult``; every
  refusal is a ``reply_err`` with an ``ErrorReply`` (a task this agent does not serve, in the
  contract or not -> ``unknown_task``; invalid payload, wrong dimension, NaN, out of bounds,
  a spline outside the joint limits -> ``invalid_request``; another episode running -> ``busy``; a controller refusing the
  configuration -> ``fault``; a bug -> ``internal``). The agent stays ready for the next one.
* publication ``<prefix>/<robot>/episode/done``: ``EpisodeDone`` after every episode it ran;
* subscriber ``<prefix>/<robot>/agent/go``: the go signal of a person who reset a robot without
  a test bench (any put; ``agent.safety``);
* subscriber ``<prefix>/<robot>/agent/estop``: ``EstopCommand`` (operator role): engage stops
  every axis within two SYNC periods and ends the running episode ``stopped``; while engaged
  every request is refused ``unavailable``; only ``engage: false`` releases it, and a put that
  does not decode engages it (a garbled stop is still a stop);
* queryable ``<prefix>/<robot>/agent/state``: ``AgentState`` (ready, waiting for go, running,
  stopped; the pacing and whether the bus is a simulated bench).

The queryable callback only validates and hands the query to one worker thread (the episode
runs there and replies when done), so a second request while an episode runs is refused at
once with ``busy`` instead of queueing behind it. ``stop()`` aborts a running episode, replies
to it, then withdraws the token and closes the session and the bus.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zenoh

from ersac_hil.agent.bus import AgentBus, BusTiming
from ersac_hil.agent.cia402 import agent_bus
from ersac_hil.agent.episode import EpisodeConfig, EpisodeRunner
from ersac_hil.agent.errors import RequestRefused
from ersac_hil.agent.safety import Safety, physical_bus
from ersac_hil.agent.trace import CanRecorder
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.zenoh_session import ZenohOptions, open_session, resolve_config
from protocol.can.busconfig import BusConfig
from protocol.can.devices import TESTBENCH
from protocol.robot import RobotDescription, default_description
from protocol.zenoh import (DEFAULT_PREFIX, AgentState, EpisodeDone, EpisodeRequest, EpisodeResult, ErrorReply,
                            EstopCommand, InvalidField, KeySpace, PayloadError)

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class AgentConfig:
    """Everything ``ersac-hil agent`` is started with.

    Attributes:
        robot, prefix: the key space (``KeySpace(robot, prefix)``).
        bus: the CAN bus. timing: SYNC period, deadline, heartbeat timeout, real-time mode.
        zenoh_mode: ``client`` (through a router) or ``peer``; zenoh_connect: endpoints
            (default: the config file's, else ``tcp/127.0.0.1:7447``); zenoh_listen: peer mode
            only; zenoh_config: a Zenoh json5 file (TLS certificates of the agent role...);
            zenoh_insecure: allow plain endpoints off loopback (``resolve_config``).
        record_can, record_format: write each episode's CAN traffic to
            ``record_can/<episode_id>.<record_format>`` (``blf`` or ``asc``; ``agent.trace``).
        record_series: write each episode's per-cycle time series to
            ``record_series/<episode_id>.npz`` after its reply (``agent.series``).
        ros2: publish for ROS 2 over rmw_zenoh's key space (``ersac_hil.ros2``), or None.
        record: write each episode as ``record/<episode_id>.mcap`` (``ersac_hil.ros2.recorder``).
        episode: what episodes do (policies, LQR weights, cost weights, limits).
        pacing: ``auto`` (real time unless the bus is a simulated bench; ``timing.realtime``
            forces real time), ``realtime`` or ``lockstep`` (``agent.safety.pacing``).
        description: the robot description (commissioning record; ``None``: the default).
        require_commissioning: serve episodes only after ``ersac-hil commission`` passed for
            this description and these nodes (``None``: on a physical bus, ``agent.safety``);
            commission_record: where that record is (default: the state directory).
    """
    robot: str
    bus: BusConfig
    zenoh_connect: tuple[str, ...]
    zenoh_mode: str = "client"
    zenoh_listen: tuple[str, ...] = ()
    zenoh_config: str | None = None
    zenoh_insecure: bool = False
    record_can: str | None = None
    record_format: str = "blf"
    record_series: str | None = None
    ros2: Ros2Options | None = None
    record: str | None = None
    prefix: str = DEFAULT_PREFIX
    timing: BusTiming = BusTiming()
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    pacing: str = "auto"
    description: RobotDescription | None = None
    require_commissioning: bool | None = None
    commission_record: str | None = None

    @property
    def keys(self) -> KeySpace:
        return KeySpace(self.robot, self.prefix)


class AgentService:
    """``start()`` / ``stop()`` (a ``ersac_hil.lifecycle.Service``)."""

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        self.keys = config.keys  # validates robot and prefix
        self.bus: AgentBus | None = None
        self.runner: EpisodeRunner | None = None
        self.session: zenoh.Session | None = None
        self._entities: list = []
        self._publisher = None
        self._busy = threading.Lock()
        self._work: queue.Queue = queue.Queue()
        self._worker: threading.Thread | None = None
        requested = config.pacing if config.pacing != "auto" or not config.timing.realtime else "realtime"
        self.safety = Safety(requested)
        self._running = False
        self.uncommissioned: str | None = None
        """Why episodes are refused until ``ersac-hil commission`` passes (``None``: they are not)."""
        self.recorder: CanRecorder | None = None
        self.feed = None  # ersac_hil.ros2.feed.Feed: the ROS 2 node and MCAP episodes
        self.episodes = 0
        self.refused = 0

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        cfg = self.config
        self.bus = agent_bus(cfg.bus, cfg.description or default_description(), cfg.timing).open()
        required = cfg.require_commissioning
        if required if required is not None else physical_bus(cfg.bus) is not None:
            from ersac_hil.agent.errors import NodeMissing
            from ersac_hil.commission.gate import refusal
            try:  # drives that are still booting: give their heartbeats a moment
                self.bus.wait_for_nodes(timeout_s=2.0)
            except NodeMissing:
                pass  # the record will not match: said in the refusal
            sdos = {d.node_id: self.bus.nodes[d.name].sdo for d in self.bus.devices}
            self.uncommissioned = refusal(cfg.description or default_description(), cfg.bus, self.bus.net,
                                          sdos, cfg.commission_record)
            if self.uncommissioned is not None:
                log.warning("%s", self.uncommissioned)
        self.runner = EpisodeRunner(self.bus, cfg.episode, safety=self.safety)
        if cfg.record_can is not None:
            self.recorder = CanRecorder(cfg.bus, cfg.record_can, cfg.record_format).start()
        for task in cfg.episode.tasks:
            self.runner.design(task)  # LQR gains once, before the first request
        options = ZenohOptions(cfg.zenoh_connect, cfg.zenoh_config, cfg.zenoh_insecure)
        zconf = resolve_config(options, mode=cfg.zenoh_mode, listen=cfg.zenoh_listen)
        self.session = open_session(zconf, insecure=cfg.zenoh_insecure)
        self._worker = threading.Thread(target=self._work_loop, name="agent-episodes", daemon=True)
        self._worker.start()
        s = self.session
        if cfg.ros2 is not None or cfg.record is not None:
            from ersac_hil.ros2.feed import Feed  # rosbags and mcap only when asked for
            self.feed = Feed.for_agent(cfg, self.bus)
            self.runner.observe = self.feed.observe
        self._publisher = s.declare_publisher(self.keys.episode_done)
        self._entities = [
            self._publisher,
            s.declare_subscriber(self.keys.agent_go, self._on_go),
            s.declare_subscriber(self.keys.agent_estop, self._on_estop),
            s.declare_queryable(self.keys.agent_state, self._on_state),
            s.declare_queryable(self.keys.episode_run, self._on_query),
            s.liveliness().declare_token(self.keys.agent_session(s.info.zid())),
            s.liveliness().declare_token(self.keys.agent_alive),
        ]
        log.info("agent %s ready: bus %s, zenoh %s %s", self.keys.root, cfg.bus.describe(),
                 cfg.zenoh_mode, ",".join(cfg.zenoh_connect + cfg.zenoh_listen))

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop_requested.set()
        self.safety.wake()
        if self._worker is not None:
            self._work.put(None)
            self._worker.join(timeout=10.0)
            self._worker = None
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception as exc:  # session may be half closed already
                log.debug("undeclare: %s", exc)
        self._entities = []
        if self.feed is not None:
            if self.bus is not None:
                self.bus.while_waiting = None
            self.feed.stop()
            self.feed = None
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        if self.recorder is not None:
            self.recorder.stop()
            self.recorder = None

    def __enter__(self) -> "AgentService":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- queries ---------------------------------------------------------------------------
    def _on_query(self, query: zenoh.Query) -> None:
        try:
            request = EpisodeRequest.from_json(query.payload if query.payload is not None else b"")
        except PayloadError as exc:
            return self._refuse(query, ErrorReply.from_exception(exc, _payload_code(exc)))
        except Exception as exc:  # never leave a query without a reply
            return self._refuse(query, ErrorReply.from_exception(exc, "internal"))
        refusal = self.safety.refusal() or self.uncommissioned
        if refusal is not None:
            return self._refuse(query, ErrorReply("unavailable", refusal))
        if not self._busy.acquire(blocking=False):
            return self._refuse(query, ErrorReply("busy", "another episode is running on this agent"))
        try:
            plan = self.runner.plan(request)  # type: ignore[union-attr]
        except (RequestRefused, InvalidField) as exc:
            self._busy.release()
            return self._refuse(query, ErrorReply.from_exception(exc, getattr(exc, "code", "invalid_request")))
        except Exception as exc:
            self._busy.release()
            return self._refuse(query, ErrorReply.from_exception(exc, "internal"))
        self._work.put((query, plan))

    def _refuse(self, query: zenoh.Query, error: ErrorReply) -> None:
        self.refused += 1
        log.info("refused %s: %s", error.code, error.reason)
        try:
            query.reply_err(error.to_json())
        finally:
            query.drop()

    def _work_loop(self) -> None:
        while True:
            item = self._work.get()
            if item is None:
                return
            if item is _IDLE_STOP:  # on this thread: the bus has one user at a time
                self._stop_idle()
                continue
            query, plan = item
            try:
                outcome = self._run(plan)
            finally:
                # free before answering: a client may send its next request the moment it
                # has the reply, and must not find the agent busy with this one
                self._busy.release()
            self._answer(query, plan, outcome)
            if self.config.record_series is not None and isinstance(outcome, EpisodeResult):
                self._write_series(outcome)

    def _run(self, plan) -> EpisodeResult | ErrorReply:
        self._running = True
        try:
            return self._run_episode(plan)
        finally:
            self._running = False

    def _run_episode(self, plan) -> EpisodeResult | ErrorReply:
        log.info("episode %s %s: started", plan.request.episode_id, plan.request.task)
        if self.recorder is not None:
            self.recorder.begin(plan.request.episode_id)
        if self.feed is not None:
            self.feed.begin(plan.request, self.bus.timing.period_s, self.bus.emcy_count)  # type: ignore[union-attr]
        result: EpisodeResult | None = None
        try:
            result = self.runner.run(plan)  # type: ignore[union-attr]
        except RequestRefused as exc:
            return ErrorReply.from_exception(exc, exc.code)
        except Exception as exc:
            log.exception("episode %s failed", plan.request.episode_id)
            return ErrorReply.from_exception(exc, "internal")
        finally:
            trace = self.recorder.end() if self.recorder is not None else ""
            mcap = self.feed.end(result) if self.feed is not None else ""
        if trace or mcap:
            result = msgspec.structs.replace(result, trace=trace, mcap=mcap)
        self.episodes += 1
        log.info("episode %s %s: %s cost %s in %.2f s", plan.request.episode_id, plan.request.task,
                 result.status, result.total_cost, result.wall_s)
        return result

    def _answer(self, query: zenoh.Query, plan, outcome: EpisodeResult | ErrorReply) -> None:
        if isinstance(outcome, ErrorReply):
            return self._refuse(query, outcome)
        try:
            query.reply(self.keys.episode_run, outcome.to_json())
        except Exception as exc:  # the querier may be gone; the episode still counts
            log.warning("reply to %s not sent: %s", plan.request.episode_id, exc)
        finally:
            query.drop()
        try:
            done = EpisodeDone(self.keys.robot, time.time(), plan.request, outcome)
            self._publisher.put(done.to_json())  # type: ignore[union-attr]
        except Exception as exc:  # publication is best effort; the reply went out
            log.warning("episode/done not published: %s", exc)

    # -- safety --------------------------------------------------------------------------
    def _on_go(self, sample: zenoh.Sample) -> None:
        if self.safety.go():
            log.warning("go: the next episode may start")
        else:
            log.warning("go ignored: the e-stop is engaged (release it first)")

    def _on_estop(self, sample: zenoh.Sample) -> None:
        try:
            command = EstopCommand.from_json(sample.payload.to_bytes())
        except Exception as exc:  # noqa: BLE001 - a stop that does not decode is still a stop
            command = EstopCommand(True, f"undecodable e-stop put ({str(exc)[:200]})")
        if command.engage:
            self.safety.engage(command.reason or "e-stop")
            log.warning("E-STOP engaged: %s", command.reason or "e-stop")
            self._work.put(_IDLE_STOP)  # after a running episode's own quick stop, or at once
        else:
            self.safety.release()
            log.warning("e-stop released%s", f": {command.reason}" if command.reason else "")

    def _stop_idle(self) -> None:
        """The e-stop between episodes: the drive profile's stop of a robot not cycling (the
        boards: NMT pre-operational again, which drops their torque, whatever left them on)."""
        try:
            self.runner.config.quick_stop.stop_idle(self.bus)  # type: ignore[union-attr]
        except Exception as exc:  # noqa: BLE001 - logged; the latch holds whatever happens
            log.error("e-stop: the idle stop failed: %s", exc)

    def state(self) -> AgentState:
        """What the agent is doing now (the ``agent/state`` reply)."""
        bench = self._simulated_bench()
        engaged = self.safety.engaged
        if engaged is not None:
            phase, detail = "stopped", f"e-stop engaged: {engaged}; release: ersac-hil estop --release"
        elif self.uncommissioned is not None:
            phase, detail = "uncommissioned", self.uncommissioned
        elif self.safety.waiting or (not bench and not self.safety.armed and not self._running):
            phase, detail = "waiting_for_go", "no test bench: reset the robot, then ersac-hil go"
        elif self._running:
            phase, detail = "running", ""
        else:
            phase, detail = "ready", ""
        requested = self.safety.pacing
        realtime = requested == "realtime" or (requested == "auto" and not bench)
        return AgentState(self.keys.robot, phase, "realtime" if realtime else "lockstep",
                          "simulated" if bench else "real", self.episodes, detail)

    def _simulated_bench(self) -> bool:
        """The bus may carry a simulator and the test bench was heard recently (no bus traffic)."""
        if self.bus is None or physical_bus(self.config.bus) is not None:
            return False
        age = self.bus.heartbeat_ages().get(TESTBENCH.name)
        return age is not None and age < self.config.episode.testbench_recent_s

    def _on_state(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.agent_state, self.state().to_json())
        except Exception as exc:  # noqa: BLE001 - never leave a query without a reply
            query.reply_err(ErrorReply.from_exception(exc, "internal").to_json())
        finally:
            query.drop()

    def _write_series(self, result: EpisodeResult) -> None:
        """The time series of the episode just answered (``agent.series``); a file that cannot
        be written is logged, the episode still counts."""
        from ersac_hil.agent.series import series_of
        from ersac_hil.episode_series import write_series

        last = self.runner.last if self.runner is not None else None
        if last is None or last.plan.request.episode_id != result.episode_id:
            return
        request = last.plan.request
        meta = {"episode_id": result.episode_id, "task": result.task, "theta": list(request.theta),
                "seed": request.seed, "status": result.status, "failures": dict(result.failures),
                "cost_terms": dict(result.cost_terms), "total_cost": result.total_cost,
                "telemetry": dict(result.telemetry)}
        try:
            directory = Path(self.config.record_series)
            directory.mkdir(parents=True, exist_ok=True)
            write_series(directory / f"{result.episode_id}.npz",
                         series_of(last, self.bus.timing.period_s, meta, self.config.episode.robot))
        except (OSError, ValueError) as exc:
            log.warning("time series of %s not written: %s", result.episode_id, exc)


_IDLE_STOP = object()
"""Work item: the e-stop's stop of a robot that runs no episode."""


def _payload_code(exc: PayloadError) -> str:
    """``unknown_task`` for a request naming a task outside the contract (so not served
    here either), ``invalid_request`` for anything else wrong with the payload."""
    return "unknown_task" if isinstance(exc, InvalidField) and exc.field == "task" else "invalid_request"
