"""request_realtime: SCHED_FIFO for every thread of the process where permitted, a clear
message and normal scheduling where not (run in child processes: the policy is process-wide);
the PM QoS wake-up latency request; KeepAwake's spinning SCHED_IDLE children."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

CODE = (
    "import os, sys, threading, time\n"
    "from protocol.can.realtime import request_realtime\n"
    "if sys.argv[1:] == ['drop']:\n"
    "    os.setgid(65534); os.setuid(65534)\n"
    "early = threading.Thread(target=time.sleep, args=(1,)); early.start()\n"
    "print(request_realtime(7))\n"
    "late = []\n"
    "t = threading.Thread(target=lambda: late.append(os.sched_getscheduler(0))); t.start(); t.join()\n"
    "def policy(tid):\n"
    "    try:\n"
    "        return os.sched_getscheduler(tid)\n"
    "    except ProcessLookupError:\n"  # a thread that ended since the listing (the joined one)
    "        return None\n"
    "tids = [int(x) for x in os.listdir('/proc/self/task')]\n"
    "print(sorted({policy(tid) for tid in tids} - {None}), late[0], os.sched_getparam(0).sched_priority)\n"
)
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _run(*args: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", CODE, *args], capture_output=True, text=True, timeout=60,
                         cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no sched_setscheduler on this platform")
def test_granted_or_refused_with_a_reason():
    message, policies = _run()
    if message.startswith("SCHED_FIFO priority 7"):
        assert policies == f"[{os.SCHED_FIFO}] {os.SCHED_FIFO} 7"  # every thread, and new ones inherit
    else:
        assert "not permitted" in message and policies.startswith(f"[{os.SCHED_OTHER}]")


@pytest.mark.skipif(not hasattr(os, "setuid") or os.geteuid() != 0, reason="needs root to drop to an unprivileged user")
def test_an_unprivileged_process_keeps_normal_scheduling_and_says_why():
    message, policies = _run("drop")  # imports done as root, then nobody (no CAP_SYS_NICE, RLIMIT_RTPRIO 0)
    assert "SCHED_FIFO not permitted" in message and "ulimit -r 7" in message
    assert policies == f"[{os.SCHED_OTHER}] {os.SCHED_OTHER} 0"


CHURN = (
    "import threading, time\n"
    "from protocol.can.realtime import request_realtime\n"
    "stop = threading.Event()\n"
    "def churn():\n"
    "    while not stop.is_set():\n"
    "        t = threading.Thread(target=lambda: None); t.start(); t.join()\n"
    "threading.Thread(target=churn, daemon=True).start()\n"
    "print(sum('refused' in request_realtime(7) for _ in range(300)))\n"
    "stop.set()\n"
)


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no sched_setscheduler on this platform")
def test_threads_ending_during_the_request_do_not_make_it_fail():
    """A thread that ends between the listing of /proc/self/task and its scheduling change is
    skipped, not reported as a refusal (the request is made while other threads come and go)."""
    out = subprocess.run([sys.executable, "-c", CHURN], capture_output=True, text=True, timeout=60,
                         cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "0"


def test_quiet_gc_freezes_start_up_and_collects_the_young_generation_rarely():
    """In a process of its own (the collector's settings are per process)."""
    code = ("import gc\n"
            "from protocol.can.realtime import GC_YOUNG_THRESHOLD, quiet_gc\n"
            "made = [[] for _ in range(1000)]\n"
            "assert gc.get_threshold()[0] < GC_YOUNG_THRESHOLD\n"
            "quiet_gc()\n"
            "assert gc.get_threshold()[0] == GC_YOUNG_THRESHOLD and gc.get_freeze_count() >= 1000\n"
            "a = []; a.append(a); del a\n"
            "assert gc.collect() >= 1  # a cycle made later is still found\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    assert done.returncode == 0, done.stderr


def test_gc_paused_switches_the_collector_off_inside_and_back_as_it_was():
    import gc

    from protocol.can.realtime import gc_paused
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
        with gc_paused():  # nested: still off, and off again after the inner block
            assert not gc.isenabled()
        assert not gc.isenabled()
    assert gc.isenabled()
    gc.disable()
    try:
        with gc_paused():
            pass
        assert not gc.isenabled()  # it was off before: it stays off
    finally:
        gc.enable()
    with pytest.raises(RuntimeError), gc_paused():
        raise RuntimeError("the loop failed")
    assert gc.isenabled()


QOS = (
    "import os, struct, sys\n"
    "from protocol.can.realtime import PM_QOS_DEVICE, hold_wakeup_latency\n"
    "print(hold_wakeup_latency(sys.argv[1]))\n"
    "print(hold_wakeup_latency(PM_QOS_DEVICE))\n"
    "if os.access(PM_QOS_DEVICE, os.R_OK):\n"
    "    with open(PM_QOS_DEVICE, 'rb') as f:\n"
    "        print(struct.unpack('=i', f.read(4))[0])\n"
)


def test_the_wake_up_latency_request_is_held_or_refused_with_a_reason(tmp_path):
    out = subprocess.run([sys.executable, "-c", QOS, str(tmp_path / "none")], capture_output=True, text=True,
                         timeout=60, cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[0] == f"no {tmp_path / 'none'}: idle states as the kernel chooses"
    if lines[1] == "CPU wake-up latency held at 0 us (PM QoS)":
        assert lines[2] == "0"  # the kernel's aggregate request while this process holds it
    else:
        assert "idle states as the kernel chooses" in lines[1]


AWAKE = (
    "import os, sys, time\n"
    "from protocol.can.realtime import KeepAwake\n"
    "awake = KeepAwake(2)\n"
    "print(awake.start(), flush=True)\n"
    "print(*awake.pids, flush=True)\n"
    "if sys.argv[1] == 'close':\n"
    "    sys.stdin.readline(); awake.close(); print(awake.pids, flush=True)\n"
    "else:\n"
    "    time.sleep(60)\n"
)


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1].startswith("Z")  # a zombie waiting for init is gone too
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE") or not os.path.isdir("/proc"), reason="no SCHED_IDLE or /proc")
@pytest.mark.parametrize("how", ["close", "parent killed"])
def test_keep_awake_spins_under_sched_idle_and_leaves_no_child(how):
    import signal

    from helpers.waiting import wait_until
    proc = subprocess.Popen([sys.executable, "-c", AWAKE, how.split()[0]], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True,
                            cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    try:
        assert proc.stdout.readline().strip() == "keep-awake: 2 SCHED_IDLE spinner(s) keep idle cores from halting"
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert len(pids) == 2
        wait_until(lambda: {os.sched_getscheduler(pid) for pid in pids} == {os.SCHED_IDLE}, timeout_s=30,
                   what="both spinners under SCHED_IDLE")
        if how == "close":
            proc.stdin.write("close\n")
            proc.stdin.flush()
            assert proc.stdout.readline().strip() == "()" and all(_gone(pid) for pid in pids)
        else:
            proc.send_signal(signal.SIGKILL)
            wait_until(lambda: all(_gone(pid) for pid in pids), timeout_s=30, what="spinners gone with their parent")
    finally:
        proc.kill()
        proc.wait(timeout=30)


def test_keep_awake_refuses_no_cores():
    from protocol.can.realtime import KeepAwake
    with pytest.raises(ValueError, match="at least one core"):
        KeepAwake(0)
