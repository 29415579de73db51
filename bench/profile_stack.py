"""Where the time goes in lock-step episodes: py-spy on the simulator, the agent and the CAN hub.

    python bench/profile_stack.py [--bus remote|zenoh|direct] [--seconds 20] [--out DIR]

Starts the stack as deployed (embedded Zenoh router in this process; the CAN transport, the
simulator ``python -m firmware_sim`` and the agent ``ersac-hil agent`` as separate processes;
``--bus direct``: CAN over Zenoh on a direct link, the simulator's bus listening and the
agent's connected to it, as ``ersac-hil demo`` runs them),
runs bracing episodes from a Zenoh client, and samples every process with
``py-spy record --nonblocking --gil --format raw`` (only threads holding the GIL, i.e. Python CPU
work, 250 Hz) for ``--seconds``.
Prints, per process, the share of samples spent inside a few functions of interest
(inclusive) and the top functions by self time. The raw stacks stay in ``--out``.

Needs ``py-spy`` (``pip install py-spy``; sampling another process needs ptrace rights).
"""
from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from episode import DIRECT, KS, ROBOT, wait_for_agent  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter, free_tcp_port  # noqa: E402
from protocol.zenoh import EpisodeRequest  # noqa: E402

#: (label, regular expression on a frame) -> inclusive share printed per process.
INTEREST = [
    ("physics: Simulator.step", r"^Simulator\.step \("),
    ("sim: SYNC handler total", r"^SimulatedRobot\._on_sync \("),
    ("sim: TPDO sampling (one sampler)", r"^TpdoSampler\.pack \("),
    ("agent: AgentBus.cycle", r"^AgentBus\.cycle \("),
    ("agent: episode loop", r"^EpisodeRunner\._loop \("),
    ("agent: LQR torque", r"^BalanceController\.torque \("),
    ("sim: axis counts (all boards)", r"^AxisCounts\.sample \("),
    ("sim: RPDO frames received", r"^SlaveNode\._rpdo_handler\.<locals>\.on_frame \("),
    ("sim: RPDOs applied at SYNC", r"^SlaveNode\.apply_commands \("),
    ("agent: Telemetry.decode", r"^Telemetry(Decoder)?\.decode \("),
    ("agent: TPDO callback", r"^AgentBus\._(on_tpdo|tpdo_handler\.<locals>\.on_frame) \("),
    ("agent: cost terms + result", r"^EpisodeRunner\._result \("),
    ("canopen: Network.notify (dispatch)", r"^Network\.notify \(canopen"),
    ("canopen: PDO decode/encode", r"^(PdoMap|PdoBase|PdoVariable|Variable)\.\w+ \(canopen"),
    ("python-can: Notifier thread", r"^Notifier\._rx_thread \("),
    ("python-can-remote (client/server)", r"\(can_remote/"),
    ("zenoh CAN plugin", r"\(ersac_hil/canbus/zenoh_bus"),
    ("learner: ERSAC.tell", r"^ERSAC\.tell \("),
]


def _spawn(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _readline_until(proc: subprocess.Popen, pattern: str, timeout_s: float = 30.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if re.search(pattern, line):
            return line
        if not line and proc.poll() is not None:
            break
    raise RuntimeError(f"{proc.args[:4]}: no /{pattern}/")


def analyse(raw: Path, top: int = 12) -> str:
    """Inclusive shares of INTEREST and the top self-time functions of one raw py-spy file."""
    total = 0
    inclusive: collections.Counter[str] = collections.Counter()
    leaf: collections.Counter[str] = collections.Counter()
    patterns = [(label, re.compile(rx)) for label, rx in INTEREST]
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack:
            continue
        n = int(count)
        frames = [re.sub(r":\d+\)$", ")", f) for f in stack.split(";")]
        total += n
        leaf[frames[-1]] += n
        for label, rx in patterns:
            if any(rx.search(f) for f in frames):
                inclusive[label] += n
    out = [f"  {total} samples holding the GIL"]
    for label, _ in INTEREST:
        if inclusive[label]:
            out.append(f"  {100 * inclusive[label] / total:5.1f}%  {label}")
    out.append("  top self time:")
    for name, n in leaf.most_common(top):
        out.append(f"  {100 * n / total:5.1f}%  {name[:110]}")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bus", choices=("remote", "zenoh", DIRECT), default="remote")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=int, default=250)
    ap.add_argument("--out", type=Path, default=None, help="keep the raw stacks here")
    args = ap.parse_args()
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        print("py-spy not found: pip install py-spy", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="ersac-profile-"))
    out.mkdir(parents=True, exist_ok=True)
    cli = [sys.executable, "-m", "ersac_hil.cli"]
    procs: dict[str, subprocess.Popen] = {}
    sampled = 0
    try:
        with EmbeddedRouter() as router:
            sim_bus = None
            if args.bus == "remote":
                port = free_tcp_port()
                procs["hub"] = _spawn([*cli, "bus", "--port", str(port)])
                _readline_until(procs["hub"], r"CAN hub: ws://")
                bus = ["--bus-interface", "remote", "--bus-channel", f"ws://127.0.0.1:{port}/"]
            elif args.bus == DIRECT:  # the simulator listens, the agent connects to it
                name, listen = f"profile-{uuid.uuid4().hex[:6]}", f"tcp/127.0.0.1:{free_tcp_port()}"
                sim_bus = ["--bus-interface", "zenoh", "--bus-channel", name, "--bus-kwargs", f"listen={listen}"]
                bus = ["--bus-interface", "zenoh", "--bus-channel", f"{name}@{listen}"]
            else:
                bus = ["--bus-interface", "zenoh", "--bus-channel",
                       f"profile-{uuid.uuid4().hex[:6]}@{router.endpoint}"]
            procs["sim"] = _spawn([sys.executable, "-m", "firmware_sim", *(sim_bus or bus)])
            _readline_until(procs["sim"], r"simulator: ")
            procs["agent"] = _spawn([*cli, "agent", "--robot", ROBOT, *bus, "--zenoh", router.endpoint])
            _readline_until(procs["agent"], r"agent ready")
            with router.open_client() as session:
                wait_for_agent(session)
                stop = threading.Event()
                episodes = [0]

                def load() -> None:
                    seed = 0
                    while not stop.is_set():
                        req = EpisodeRequest(f"prof-{seed}", "bracing", (0.5,), seed)
                        list(session.get(KS.episode_run, payload=req.to_json(), timeout=120))
                        seed += 1
                        episodes[0] += 1

                worker = threading.Thread(target=load, daemon=True)
                worker.start()
                time.sleep(1.0)  # past the first episode's set-up
                first = episodes[0]
                spies = {name: subprocess.Popen(
                    [spy, "record", "--nonblocking", "--gil", "-r", str(args.rate), "-f", "raw",
                     "-d", str(int(args.seconds)), "-p", str(p.pid), "-o", str(out / f"{name}.txt")],
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for name, p in procs.items()}
                for s in spies.values():
                    s.wait()
                sampled = episodes[0] - first  # finished while the processes were sampled
                stop.set()
                worker.join(timeout=60)
    finally:
        for p in procs.values():
            p.terminate()
            p.communicate(timeout=10)
    print(f"profile of lock-step bracing episodes over '{args.bus}', {args.seconds:g} s at {args.rate} Hz, "
          f"{sampled} episodes while sampled ({episodes[0]} in all); load average {os.getloadavg()[0]:.2f}; "
          f"raw stacks in {out}")
    cycles = sampled * 400  # 2 s bracing episodes at 200 Hz (set-up included in the wall time)
    for name in procs:
        raw = out / f"{name}.txt"
        if raw.exists():
            print(f"\n[{name}]\n{analyse(raw)}")
            held = sum(int(line.rpartition(" ")[2]) for line in raw.read_text().splitlines() if " " in line)
            if cycles:
                print(f"  GIL held about {1e6 * held / args.rate / cycles:.0f} us per cycle ({cycles} cycles)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
