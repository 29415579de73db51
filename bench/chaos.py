"""The faults of a real deployment, measured: each against the run without it.

    python bench/chaos.py [--faults kill-all,router-restart,disk-full,partition,partition-agent,rogue-sync,...]
                          [--episodes 6] [--seed 3]

Router, simulator, agent and daemon as separate processes on loopback (the partition: across
two network namespaces made for it, skipped where they cannot be made), a real SQLite store,
a few lock-step bracing episodes per run (``ersac_hil.stack.faults``, the same faults the
end-to-end tests assert on, ``tests/e2e/test_faults.py``):

* kill-all: router, simulator, agent and daemon SIGKILLed at once mid-episode, then started again;
* router-restart: the router SIGKILLed mid-episode and started again on its endpoint;
* disk-full: no file of the daemon may grow (``RLIMIT_FSIZE`` 0) after two episodes; then a
  daemon with space started again;
* partition: the daemon's veth down for 12 s (longer than Zenoh's 10 s lease) mid-episode,
  then up (the router beside the robot);
* partition-agent: the robot's veth down for 12 s mid-episode, then up (the router beside the
  daemon: the agent, running the episode on, is cut off from it);
* rogue-KIND: a faulty node on the robot's CAN bus while the episode it hit runs, one row per
  kind: rogue-sync (a second SYNC producer), rogue-tpdo-twice (a forged TPDO of the right
  length, so twice in one cycle), rogue-wrong-length (a PDO one byte short), rogue-sdo-answer
  (SDO answers nobody asked for), rogue-babbler (a flood on COB-ID 0x001), rogue-error-frame
  (error frames); a kind the agent missed would leave that episode ok (differing where the
  node changed its data; tests/e2e/test_faults.py asserts it ends as a bus fault).

Per fault: when it was detected (seconds from the fault to the daemon's first line other than
progress, or its exit), when the run went on (seconds from the end of the fault - restart,
link up - to the next ok episode stored), the episodes of the uninterrupted run lost, recorded
twice or differing, the updates differing, and the daemon's exit statuses (one per start).
Timing figures move with the machine's load (printed). No pass/fail.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

for key, value in (("OPENBLAS_NUM_THREADS", "1"), ("OMP_NUM_THREADS", "1"), ("MUJOCO_GL", "egl")):
    os.environ.setdefault(key, value)
from ersac_hil.stack.faults import (FAULTS, NETNS_FAULTS, RUN_S, Outcome, faulted_rig,  # noqa: E402
                                   netns_unavailable, reference_run, tally)


def _seconds(value: float | None) -> str:
    return "-" if value is None or value != value else f"{value:.1f} s"


def _row(name: str, outcome: Outcome | None, reference, reason: str = "") -> list[str]:  # noqa: ANN001
    if outcome is None:
        return [name, "-", "-", "-", "-", "-", "-", reason]
    t = tally(reference, outcome.history)
    return [name, _seconds(outcome.detected_s), _seconds(outcome.recovered_s), str(t.lost), str(t.duplicated),
            str(t.differing), str(t.updates_differing), " -> ".join(map(str, outcome.exits))]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--faults", default=",".join(FAULTS), help=f"comma-separated, of {', '.join(FAULTS)}")
    p.add_argument("--episodes", type=int, default=6)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--out", type=Path, help="keep the stores and logs here (default: a temporary directory)")
    args = p.parse_args(argv)
    names = [n.strip() for n in args.faults.split(",") if n.strip()]
    unknown = [n for n in names if n not in FAULTS]
    if unknown:
        p.error(f"unknown fault(s) {unknown}; known: {', '.join(FAULTS)}")
    with tempfile.TemporaryDirectory(prefix="chaos-") as tmp:
        work = args.out or Path(tmp)
        started = time.monotonic()
        reference = reference_run(work / "reference", args.seed, args.episodes, RUN_S)
        print(f"reference: {len(reference.episodes)} episodes, {len(reference.updates)} updates "
              f"({time.monotonic() - started:.0f} s)", flush=True)
        rows = []
        for name in names:
            reason = netns_unavailable() if name in NETNS_FAULTS else None
            if reason:
                rows.append(_row(name, None, reference, f"skipped: {reason}"))
                continue
            with faulted_rig(name, work / name, args.seed, args.episodes) as rig:
                outcome = FAULTS[name](rig)
            rows.append(_row(name, outcome, reference))
            print(f"{name}: done", flush=True)
    header = ["fault", "detected after", "recovered after", "lost", "duplicated", "differing",
              "updates differing", "exit status"]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    print()
    for r in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    print(f"\n{args.episodes} lock-step bracing episodes a run, seed {args.seed}; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
