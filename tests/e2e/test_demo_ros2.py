"""``ersac-hil demo --ros2``: the whole stack (router, simulator, agent with the ROS 2 bridge and
MCAP recording, daemon) learns a few episodes; every episode the daemon stored names its MCAP
file, the files open with mcap + mcap-ros2-support, and ``report --mcap`` exports the run with
every episode."""
from __future__ import annotations

import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ersac_hil.daemon.store import Store
from helpers.processes import group_killed_on_exit

pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]
ROOT = Path(__file__).resolve().parents[2]


def _topics(path: Path) -> dict[str, list]:
    got = defaultdict(list)
    with open(path, "rb") as f:
        for _, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic].append(decoded)
    return got


def test_demo_ros2_records_every_episode_and_the_run_exports(tmp_path):
    out = tmp_path / "report"
    with group_killed_on_exit(subprocess.Popen(
            [sys.executable, "-m", "ersac_hil.cli", "demo", "--out", str(out), "--episodes", "3", "--seed", "4",
             "--ros2"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)) as proc:
        output, _ = proc.communicate(timeout=360)
    assert proc.returncode == 0, output
    with Store(out / "demo.db", readonly=True) as store:
        (run,) = store.runs()
        attempts = [a for a in store.attempts(run.run_id) if a.status == "ok"]
    assert len(attempts) == 3 and all(a.mcap == f"{a.episode_id}.mcap" for a in attempts)
    for a in attempts:
        topics = _topics(out / "mcap" / a.mcap)
        assert len(topics["/ubot1/joint_states"]) == round(a.telemetry["n_cycles"])
        assert [m.hardware_id for m in topics["/ubot1/episode"]] == [a.episode_id] * 2
        # CAN over Zenoh (the demo's direct link): the agent bus's tap hands on every SYNC it sent
        # and the TPDOs it received, burst by burst
        counts = Counter(f.id for f in topics["/ubot1/can"])
        assert counts[0x80] == counts[0x1A0] == round(a.telemetry["n_cycles"])  # SYNCs sent, IMU TPDOs received
        assert any(0x701 <= cob_id <= 0x77F for cob_id in counts)  # the nodes' heartbeats
    export = tmp_path / "run.mcap"
    r = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "report", "latest", "--db", str(out / "demo.db"),
                        "--mcap", str(export), "--mcap-dir", str(out / "mcap")],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    topics = _topics(export)
    assert {m.hardware_id for m in topics["/ubot1/episode"]} >= {a.episode_id for a in attempts}
    assert len(topics["/ubot1/joint_states"]) == sum(round(a.telemetry["n_cycles"]) for a in attempts)
    assert topics["/ubot1/learner/updates"]
