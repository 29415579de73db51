"""Faults of a real deployment, injected into a real stack: the Zenoh router, the firmware
simulator, the agent and the learner daemon as separate processes (``ersac-hil router/sim/
agent/daemon``), each of which can be killed, restarted, cut off or starved of disk, and what a
run's store holds afterwards compared with an uninterrupted run of the same seed.

Used by ``tests/e2e/test_faults.py`` (asserts) and ``bench/chaos.py`` (measures and prints),
on the stack's own process supervision (``Child``: a process group each, a log file, gone with
this process). No pytest in here: the bench runs without it. Network namespaces need root.
"""
from __future__ import annotations

import dataclasses
import functools
import os
import re
import resource
import signal
import subprocess
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ersac_hil.daemon.store import Store
from ersac_hil.zenoh_session import free_tcp_port

from .process import Child, child_env, cli_argv

__all__ = ["FAULTS", "NETNS_FAULTS", "ROGUE_NODES", "RUN_S", "History", "Netns", "Outcome", "Rig", "Tally",
           "disk_full", "faulted_rig", "history", "kill_all", "netns_unavailable", "partition", "reference_run",
           "robot_cob_ids", "rogue_can", "rogue_frames", "router_restart", "tally", "wait"]

ROBOT = "ubot1"
TASK = "bracing"
START_S = 120.0
"""How long a child may take to come up (a loaded machine starts MuJoCo slowly)."""


def wait(predicate: Callable[[], object], timeout_s: float, what: str, poll_s: float = 0.05) -> float:
    """Poll ``predicate`` until it holds; returns when (``time.monotonic()``); ``TimeoutError``
    naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not within {timeout_s:g} s")
        time.sleep(poll_s)
    return time.monotonic()


# --------------------------------------------------------------------------- what a store holds
@dataclass(frozen=True)
class History:
    """A run as its store holds it. ``episodes``: the ok episodes as (idx, theta, seed, cost
    terms, update idx) in store order; ``updates``: (idx, theta before, theta after, J, r,
    state, idx of the episodes that fed it); ``attempts``: (idx, attempt, status) of every
    attempt; ``finished``: the ``finished_s`` wall times of the ok episodes."""

    status: str
    episodes: tuple
    updates: tuple
    attempts: tuple
    finished: tuple[float, ...]


def history(db: Path) -> History | None:
    """The store's one run, or ``None`` while it has none (or is being created)."""
    if not db.exists():
        return None
    try:
        with Store(db, readonly=True) as store:
            runs = store.runs()
            if not runs:
                return None
            (run,) = runs
            attempts = store.attempts(run.run_id)
            ok = [a for a in attempts if a.ok]
            idx_of = {e.episode_id: e.idx for e in ok}
            return History(
                run.status,
                tuple((e.idx, e.theta, e.seed, tuple(sorted(e.cost_terms.items())), e.update_idx) for e in ok),
                tuple((u.idx, u.theta_before, u.theta_after, u.J, u.r, repr(sorted(u.state.items())),
                       tuple(idx_of[i] for i in u.episodes)) for u in store.updates(run.run_id)),
                tuple((a.idx, a.attempt, a.status) for a in attempts),
                tuple(e.finished_s for e in ok))
    except Exception:  # noqa: BLE001 - the writer may be creating the schema right now
        return None


def n_ok(db: Path) -> int:
    h = history(db)
    return len(h.episodes) if h else 0


@dataclass(frozen=True)
class Tally:
    """A faulted run against the run without the fault: episodes of the reference missing
    (``lost``), idx recorded ok more than once (``duplicated``), idx whose request or costs
    differ (``differing``), updates that differ."""

    lost: int
    duplicated: int
    differing: int
    updates_differing: int

    @property
    def exact(self) -> bool:
        return not (self.lost or self.duplicated or self.differing or self.updates_differing)


def tally(reference: History, run: History) -> Tally:
    ref = {e[0]: e for e in reference.episodes}
    got: dict[int, list[tuple]] = {}
    for e in run.episodes:
        got.setdefault(e[0], []).append(e)
    ref_updates = dict((u[0], u) for u in reference.updates)
    return Tally(lost=sum(idx not in got for idx in ref),
                 duplicated=sum(len(v) - 1 for v in got.values()),
                 differing=sum(idx in ref and v[0] != ref[idx] for idx, v in got.items()),
                 updates_differing=sum(ref_updates.get(u[0]) != u for u in run.updates)
                 + sum(i not in {u[0] for u in run.updates} for i in ref_updates))


# --------------------------------------------------------------------------- network namespaces
def netns_unavailable() -> str | None:
    """Why the test cannot make network namespaces here, or ``None``."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    name = f"ersac-probe-{uuid.uuid4().hex[:8]}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "delete", name], capture_output=True)
    return None


class Netns:
    """Two network namespaces joined by a veth pair, made here and deleted by :meth:`close`:
    ``daemon`` (address ``DAEMON_IP``) and ``robot`` (``ROBOT_IP``), loopback up in both. Only
    these two addresses, inside the two namespaces; nothing in the machine's own namespace."""

    DAEMON_IP = "10.199.0.1"
    ROBOT_IP = "10.199.0.2"

    def __init__(self) -> None:
        tag = uuid.uuid4().hex[:8]
        self.daemon, self.robot = f"ersac-d-{tag}", f"ersac-r-{tag}"
        self._ends = {"daemon": f"vd{tag}", "robot": f"vr{tag}"}
        self._made: list[str] = []
        try:
            for ns in (self.daemon, self.robot):
                self._ip("netns", "add", ns)
                self._made.append(ns)
            self._ip("link", "add", self._ends["daemon"], "netns", self.daemon, "type", "veth", "peer", "name",
                     self._ends["robot"], "netns", self.robot)
            for ns, dev, ip in ((self.daemon, self._ends["daemon"], self.DAEMON_IP),
                                (self.robot, self._ends["robot"], self.ROBOT_IP)):
                self._ip("-n", ns, "addr", "add", f"{ip}/30", "dev", dev)
                self._ip("-n", ns, "link", "set", dev, "up")
                self._ip("-n", ns, "link", "set", "lo", "up")
        except Exception:
            self.close()
            raise

    @staticmethod
    def _ip(*args: str) -> None:
        done = subprocess.run(["ip", *args], capture_output=True, text=True)
        if done.returncode != 0:
            raise OSError(f"ip {' '.join(args)}: {done.stderr.strip()}")

    def prefix(self, ns: str) -> list[str]:
        """The argv prefix running a command inside ``ns`` (``ip netns exec`` execs it: same pid)."""
        return ["ip", "netns", "exec", ns]

    def link(self, up: bool, side: str = "daemon") -> None:
        """``side``'s end of the veth (``daemon`` or ``robot``) up or down: a partition
        between the two namespaces, as seen first by that side."""
        ns = self.daemon if side == "daemon" else self.robot
        self._ip("-n", ns, "link", "set", self._ends[side], "up" if up else "down")

    def close(self) -> None:
        for ns in reversed(self._made):  # deleting a namespace deletes its veth end and the peer
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        self._made = []


# --------------------------------------------------------------------------- the stack
class Rig:
    """Router, simulator, agent and daemon of one learning run as separate child processes
    (``ersac_hil.stack.Child``: own process group, log file, killed with this process), each
    started and stopped on its own, so that a fault can hit any of them.

    The router's endpoint is fixed at construction (a restarted router listens where the
    sessions reconnect). With ``netns``, the daemon runs in its namespace and the simulator and
    agent in the robot's; the router beside the robot (``router_beside="robot"``: the daemon
    connects over the veth) or beside the daemon (``"daemon"``: the agent connects over it).

    Args:
        work: directory of the store (``work/run.db``) and the children's logs.
        seed: the run's seed (daemon ``--seed``; the simulator's base seed too).
        episodes: the run's budget.
        netns: run across this namespace pair.
        router_beside: with ``netns``, the namespace of the router.
    """

    def __init__(self, work: Path, seed: int, episodes: int, netns: Netns | None = None,
                 router_beside: str = "robot") -> None:
        self.work, self.seed, self.episodes, self.netns = work, seed, episodes, netns
        self.router_beside = router_beside
        self.db = work / "run.db"
        self.logs = work / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        host = (Netns.ROBOT_IP if router_beside == "robot" else Netns.DAEMON_IP) if netns else "127.0.0.1"
        self.endpoint = f"tcp/{host}:{free_tcp_port()}"
        self.can_channel = ""
        """The simulator/agent CAN-over-Zenoh channel (``name@endpoint`` of the simulator's listener)."""
        self.children: dict[str, Child] = {}
        self.pids: list[int] = []
        """Every child process ever started."""
        self.said: list[tuple[float, str, str]] = []
        """(``time.monotonic()``, child, line) of every output line of every child, in order."""
        self._env = child_env()
        self._starts: dict[str, int] = {}

    def _launch(self, name: str, argv: Sequence[str], ns: str | None) -> Child:
        n = self._starts[name] = self._starts.get(name, 0) + 1
        prefix = self.netns.prefix(ns) if self.netns and ns else []
        child = Child(name if n == 1 else f"{name}-{n}", [*prefix, *argv], self.logs, self._env,
                      echo=lambda line: self.said.append((time.monotonic(), name, line)))
        self.children[name] = child
        self.pids.append(child.pid)
        return child

    def first_line(self, name: str, since: float, pattern: str) -> float | None:
        """When ``name`` (any of its starts) first printed a line matching ``pattern`` after ``since``."""
        regex = re.compile(pattern)
        return next((t for t, who, line in list(self.said) if who == name and t > since and regex.search(line)), None)

    def output(self, name: str = "daemon") -> str:
        """Everything ``name`` printed, over all its starts."""
        return "\n".join(line for _, who, line in list(self.said) if who == name)

    def _robot_ns(self) -> str | None:
        return self.netns.robot if self.netns else None

    def _daemon_ns(self) -> str | None:
        return self.netns.daemon if self.netns else None

    @property
    def cut_off(self) -> str:
        """The namespace a partition cuts off from the router: the one without it."""
        return "daemon" if self.router_beside == "robot" else "robot"

    def start_router(self) -> Child:
        insecure = ["--insecure"] if self.netns else []
        router = self._launch("router", cli_argv("router", "--zenoh", self.endpoint, *insecure),
                              self._robot_ns() if self.router_beside == "robot" else self._daemon_ns())
        router.wait_for(r"Zenoh router: ", START_S)
        return router

    def start_robot(self) -> None:
        """Simulator, then the agent, its CAN over Zenoh on a direct link to the simulator."""
        listen = f"tcp/127.0.0.1:{free_tcp_port()}"
        bus = f"ersac-{ROBOT}"
        self.can_channel = f"{bus}@{listen}"
        sim = self._launch("sim", cli_argv("sim", "--bus-interface", "zenoh", "--bus-channel", bus,
                                           "--bus-kwargs", f"listen={listen}", "--seed", str(self.seed)),
                           self._robot_ns())
        sim.wait_for(r"^simulator: \d+ nodes", START_S)
        insecure = ["--insecure"] if self.netns else []
        self._launch("agent", cli_argv("-v", "agent", "--robot", ROBOT, "--bus-interface", "zenoh", "--bus-channel",
                                       self.can_channel, "--zenoh", self.endpoint, *insecure),
                     self._robot_ns()).wait_for(r"^agent ready: ", START_S)

    def start_daemon(self) -> Child:
        """The daemon: a new run on an empty store, else it resumes the store's unfinished run."""
        insecure = ["--insecure"] if self.netns else []
        return self._launch("daemon", cli_argv(
            "daemon", "--robot", ROBOT, "--task", TASK, "--episodes", str(self.episodes), "--seed", str(self.seed),
            "--kappa", "2", "--zenoh", self.endpoint, *insecure, "--db", str(self.db), "--backoff", "0.05,0.5",
            "--agent-wait", "300"), self._daemon_ns())

    def start(self) -> Rig:
        self.start_router()
        self.start_robot()
        self.start_daemon()
        return self

    def kill(self, *names: str) -> None:
        """SIGKILL the process groups of ``names`` (default: every child) at once."""
        for name in names or list(self.children):
            child = self.children.get(name)
            if child is not None and child.alive():
                os.killpg(child.pid, signal.SIGKILL)
        for name in names or list(self.children):
            child = self.children.pop(name, None)
            if child is not None:
                child.stop(0)

    def limit_file_size(self, name: str, size: int) -> None:
        """``RLIMIT_FSIZE`` of the running ``name``: no file it writes grows past ``size`` bytes
        (the disk is full for it); Python ignores SIGXFSZ, so a write fails with EFBIG."""
        resource.prlimit(self.children[name].pid, resource.RLIMIT_FSIZE, (size, size))

    def daemon_exit(self, timeout_s: float) -> int:
        """The daemon's exit status (it must end by itself within ``timeout_s``)."""
        daemon = self.children["daemon"]
        code = daemon.proc.wait(timeout_s)
        daemon.stop(0)
        return code

    def close(self) -> None:
        """Stop every child: the daemon first, then the robot side, then the router."""
        for name in ("daemon", "agent", "sim", "router"):
            child = self.children.pop(name, None)
            if child is not None:
                child.stop()
        self.kill()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- the faults
RUN_S = 300.0
"""How long a run of a few episodes may take at most (bounds a hang; no statement of speed)."""
PARTITION_S = 12.0
"""How long the partition lasts: longer than Zenoh's lease (10 s, the default
``transport/link/tx/lease``), so the cut-off session surely expires. A cut of about the lease
races its expiry (measured: detected after 9.9-10.0 s of a 10 s cut), and a shorter one TCP
bridges: the session lives on and nothing is to recover."""
PROGRESS = r"episode +\d+/\d+ |update |run \S+ finished"
"""The daemon's lines of a run going as it should; any other line after a fault is its detection."""


@dataclass(frozen=True)
class Outcome:
    """One faulted run: ``history``, its store at the end; ``during``, the store while the
    fault lasted (read once it took effect; ``None`` where the run went on meanwhile); the
    daemon's exit statuses (one per start, in order); ``detected_s``, seconds from the fault to
    its first sign (a daemon line other than progress, or the daemon's exit; ``None``: nothing
    showed); ``recovered_s``, seconds from the end of the fault (restart, link up) until the
    next ok episode was stored; ``output``, everything the daemon printed; ``answered``, the
    agent's own account of the episodes it ran to their end, (episode id, status) in order
    (whether or not its answer reached the daemon); ``hits``, what :func:`rogue_can` hit."""

    fault: str
    history: History
    during: History | None
    exits: tuple[int, ...]
    detected_s: float | None
    recovered_s: float | None
    output: str
    answered: tuple[tuple[str, str], ...] = ()
    hits: tuple[tuple[str, int, int], ...] = ()


def _mid_episode(rig: Rig, after: int) -> History:
    """Wait until ``after`` episodes are stored ok and the next one runs (its attempt pending);
    the store as it was then."""
    seen: list[History] = []

    def running() -> bool:
        h = history(rig.db)
        seen[:] = [h] if h else []
        return bool(h and len(h.episodes) >= after and any(status == "pending" for *_, status in h.attempts))
    wait(running, RUN_S, f"{after} ok episodes and one running")
    return seen[0]


def _recovered(rig: Rig, since_wall: float) -> float:
    """Seconds from ``since_wall`` (``time.time()``) to the first ok episode stored after it."""
    h = history(rig.db)
    later = [t for t in (h.finished if h else ()) if t is not None and t > since_wall]
    return min(later) - since_wall if later else float("nan")


def _finish(rig: Rig, fault: str, during: History | None, exits: Sequence[int], t_fault: float,
            t_end_wall: float, detected: float | None = None) -> Outcome:
    """Let the daemon run to its end; the outcome."""
    code = rig.daemon_exit(RUN_S)
    if detected is None:
        seen = rig.first_line("daemon", t_fault, rf"^(?!{PROGRESS}).")
        detected = None if seen is None else seen - t_fault
    h = history(rig.db)
    assert h is not None
    answered = tuple(m.groups() for m in re.finditer(rf"episode (\S+) {TASK}: (\w+) cost", rig.output("agent")))
    return Outcome(fault, h, during, (*exits, code), detected, _recovered(rig, t_end_wall), rig.output(), answered)


def kill_all(rig: Rig) -> Outcome:
    """Every process SIGKILLed at once mid-episode, then the whole stack started again."""
    rig.start()
    _mid_episode(rig, 2)
    t_fault = time.monotonic()
    rig.kill()
    during = history(rig.db)
    t_end_wall = time.time()
    rig.start()
    seen = rig.first_line("daemon", t_fault, r"interrupted attempt")
    return _finish(rig, "kill-all", during, (-signal.SIGKILL,), t_fault, t_end_wall,
                   None if seen is None else seen - t_fault)


def router_restart(rig: Rig) -> Outcome:
    """The router SIGKILLed mid-episode and started again on its endpoint; the others stay."""
    rig.start()
    _mid_episode(rig, 2)
    t_fault = time.monotonic()
    rig.kill("router")
    rig.start_router()
    return _finish(rig, "router-restart", None, (), t_fault, time.time())


def disk_full(rig: Rig) -> Outcome:
    """No file of the daemon may grow any more (``RLIMIT_FSIZE`` 0: every write fails) after
    two episodes: the daemon must stop the run by itself; then a daemon with space resumes it."""
    rig.start()
    wait(lambda: n_ok(rig.db) >= 2, RUN_S, "2 ok episodes")
    t_fault = time.monotonic()
    rig.limit_file_size("daemon", 0)
    code = rig.daemon_exit(RUN_S)
    detected = time.monotonic() - t_fault
    during = history(rig.db)
    t_end_wall = time.time()
    rig.start_daemon()
    return _finish(rig, "disk-full", during, (code,), t_fault, t_end_wall, detected)


def partition(rig: Rig) -> Outcome:
    """The link between the two namespaces down for ``PARTITION_S`` mid-episode, then up: the
    side without the router (``Rig.cut_off``: the daemon, or the agent with its simulator) cut
    off. ``during``: the store when the link went down (the attempt it cut pending)."""
    assert rig.netns is not None
    rig.start()
    during = _mid_episode(rig, 2)
    t_fault = time.monotonic()
    rig.netns.link(False, rig.cut_off)
    try:
        time.sleep(PARTITION_S)  # the fault's duration, not a synchronisation
    finally:
        rig.netns.link(True, rig.cut_off)
    return _finish(rig, "partition" if rig.cut_off == "daemon" else "partition-agent", during, (), t_fault,
                   time.time())


ROGUE_NODES: dict[str, str] = {
    "sync": "a second SYNC producer",
    "tpdo-twice": "a second producer of the IMU's TPDO, of the right length (twice in one cycle)",
    "wrong-length": "the IMU's TPDO one byte short",
    "sdo-answer": "SDO answers nobody asked for, on the agent's SDO client COB-ID of the IMU",
    "babbler": "a babbling node flooding the high-priority COB-ID 0x001 (50 frames a tick)",
    "error-frame": "error frames",
}
"""The faulty CAN nodes of :func:`rogue_can`: kind -> what it sends every ``ROGUE_TICK_S``."""
ROGUE_TICK_S = 0.02


def robot_cob_ids() -> set[int]:
    """Every COB-ID of the robot's own traffic (the board profile): NMT, SYNC, every node's
    PDOs, EMCY, SDO requests and answers and heartbeats, and the agent's heartbeat."""
    from protocol.can import AGENT_NODE_ID, cobid
    from protocol.can.devices import DEVICES
    from protocol.can.pdo import pdo_maps

    ids = {cobid.NMT, cobid.SYNC, cobid.heartbeat(AGENT_NODE_ID)}
    for dev in DEVICES:
        ids |= {p.cob_id for p in pdo_maps(dev)}
        ids |= {cobid.emcy(dev.node_id), cobid.sdo_rx(dev.node_id), cobid.sdo_tx(dev.node_id),
                cobid.heartbeat(dev.node_id)}
    return ids


def rogue_frames(kind: str) -> list:
    """The frames the rogue node of ``kind`` (of :data:`ROGUE_NODES`) sends every tick."""
    import can

    from protocol.can import cobid
    from protocol.can.devices import DEVICES
    from protocol.can.pdo import pdo_maps, pdo_struct

    def frame(cob_id: int, data: bytes = b"", error: bool = False) -> can.Message:
        return can.Message(arbitration_id=cob_id, data=data, is_error_frame=error, is_extended_id=False)
    imu = next(d for d in DEVICES if d.name == "imu")
    tpdo = min((p for p in pdo_maps(imu) if p.direction == "tpdo" and 1 <= p.transmission_type <= 240),
               key=lambda p: p.cob_id)  # a synchronous TPDO: exactly one a SYNC cycle
    size = pdo_struct(tpdo).size
    makers = {
        "sync": lambda: [frame(cobid.SYNC)],
        "tpdo-twice": lambda: [frame(tpdo.cob_id, bytes([0x55] * size))],
        "wrong-length": lambda: [frame(tpdo.cob_id, bytes(size - 1))],
        "sdo-answer": lambda: [frame(cobid.sdo_tx(imu.node_id), bytes([0x43, 0x18, 0x10, 1, 0, 0, 0, 0]))],
        "babbler": lambda: [frame(0x001, bytes(8))] * 50,
        "error-frame": lambda: [frame(0x000, bytes(8), error=True)],
    }
    return makers[kind]()


def rogue_can(rig: Rig, kind: str = "sync", *more: str, after: int = 2) -> Outcome:
    """A rogue node on the robot's CAN bus mid-episode (its own bus on the simulator's listener)
    sending the frames of ``kind`` (:data:`ROGUE_NODES`) every ``ROGUE_TICK_S`` while the episode
    it hit runs (the attempt pending once ``after`` episodes are ok), then gone: however that
    attempt ended (a bus fault, or ok if the agent missed the node), the run goes on without the
    node. Each of ``more`` kinds then hits the next episode the same way (its attempt pending
    once the one before is ok). ``during``: the store when the first node came; ``hits``: (kind,
    idx, attempt) of every attempt a node hit."""
    import can

    rig.start()
    rogue = can.Bus(interface="zenoh", channel=rig.can_channel)

    def running(hit: tuple[int, int]) -> bool:
        h = history(rig.db)
        return h is None or any((idx, attempt) == hit and status == "pending" for idx, attempt, status in h.attempts)
    hits, during, t_fault = [], None, None
    try:
        for n, name in enumerate((kind, *more)):
            frames = rogue_frames(name)
            seen = _mid_episode(rig, after + n)
            (hit,) = [(idx, attempt) for idx, attempt, status in seen.attempts if status == "pending"]
            hits.append((name, *hit))
            if during is None:
                during, t_fault = seen, time.monotonic()
            deadline = time.monotonic() + RUN_S
            while running(hit):
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the episode under {ROGUE_NODES[name]} did not end")
                for msg in frames:
                    rogue.send(msg)
                time.sleep(ROGUE_TICK_S)  # the node's own rate, not a synchronisation
    finally:
        rogue.shutdown()
    outcome = _finish(rig, "rogue-" + "+".join((kind, *more)), during, (), t_fault, time.time())
    return dataclasses.replace(outcome, hits=tuple(hits))


FAULTS: dict[str, Callable[[Rig], Outcome]] = {
    "kill-all": kill_all, "router-restart": router_restart, "disk-full": disk_full, "partition": partition,
    "partition-agent": partition, **{f"rogue-{kind}": functools.partial(rogue_can, kind=kind) for kind in ROGUE_NODES}}
NETNS_FAULTS = {"partition": "robot", "partition-agent": "daemon"}
"""The faults run across two network namespaces -> the namespace of the router (``Rig.router_beside``;
the other side is the one cut off)."""


@contextmanager
def faulted_rig(fault: str, work: Path, seed: int, episodes: int) -> Iterator[Rig]:
    """The rig ``fault`` runs on (across a namespace pair made here and deleted after, for the
    faults of :data:`NETNS_FAULTS`); every child stopped at the end."""
    beside = NETNS_FAULTS.get(fault)
    netns = Netns() if beside else None
    try:
        with Rig(work, seed, episodes, netns, router_beside=beside or "robot") as rig:
            yield rig
    finally:
        if netns is not None:
            netns.close()


def reference_run(work: Path, seed: int, episodes: int, timeout_s: float) -> History:
    """The run without any fault, to its end."""
    with Rig(work, seed, episodes).start() as rig:
        code = rig.daemon_exit(timeout_s)
        assert code == 0, rig.output()
    h = history(rig.db)
    assert h is not None and h.status == "finished"
    return h

