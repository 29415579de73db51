"""``ersac-hil demo --ros2``: the whole stack (router, simulator, agent with the ROS 2 bridge and
MCAP recording, daemon) learns a few episodes; every episode the daemon stored names its MCAP
file, the files open with mcap + mcap-ros2-support, and ``report --mcap`` exports the run with
every episode; a zenoh-python subscriber sees the ROS 2 node during it."""
from __future__ import annotations

import re
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from ersac_hil.daemon.store import Store
from ersac_hil.ros2 import names
from ersac_hil.zenoh_session import make_config, session_scope
from helpers.processes import group_killed_on_exit, lines_until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]
ROOT = Path(__file__).resolve().parents[2]


def _topics(path: Path) -> dict[str, list]:
    got = defaultdict(list)
    with open(path, "rb") as f:
        for _, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic].append(decoded)
    return got


def test_demo_ros2_records_every_episode_and_the_run_exports(tmp_path):
    """During the demo a zenoh-python client on its router subscribes to the documented keys
    and tokens: every sample decodes with rosbags' Jazzy typestore, its key's type hash is
    rosbags' RIHS01 hash, the tokens parse, attachments count up by one with rising stamps."""
    out = tmp_path / "report"
    samples, tokens = [], []
    with group_killed_on_exit(subprocess.Popen(
            [sys.executable, "-m", "ersac_hil.cli", "demo", "--out", str(out), "--episodes", "3", "--seed", "4",
             "--ros2"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)) as proc:
        head = lines_until(proc, r"demo: router (\S+),", 180)
        endpoint = re.search(r"demo: router (\S+),", head[-1]).group(1)
        with session_scope(make_config("client", connect=[endpoint])) as session:
            live = session.liveliness().declare_subscriber(
                "@ros2_lv/0/**", lambda s: tokens.append(str(s.key_expr)), history=True)
            sub = session.declare_subscriber("0/**", lambda s: samples.append(
                (str(s.key_expr), s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes())))
            rest, _ = proc.communicate(timeout=360)
            sub.undeclare()
            live.undeclare()
    output = "".join(head) + rest
    assert proc.returncode == 0, output
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    per_key = defaultdict(list)
    for key, payload, attachment in samples:
        domain, namespace, topic, dds, type_hash = key.split("/")
        assert (domain, namespace) == ("0", "ubot1")
        typename = names.ros_type(dds)
        assert type_hash == jazzy.hash_rihs01(typename)
        jazzy.deserialize_cdr(payload, typename)
        per_key[key].append(names.parse_attachment(attachment))
    assert {k.split("/")[2] for k in per_key} >= {"joint_states", "imu", "episode"}
    for key, atts in per_key.items():
        seqs, stamps = [a[0] for a in atts], [a[1] for a in atts]
        # strictly increasing, as rmw_zenoh reads them; a KEEP_LAST publisher (Zenoh's congestion
        # control "drop", as rmw_zenoh's) may lose a sample when the machine is overloaded: a gap
        # (CI at load ~30 saw 1, 3, 4, 5, 6 on the episode topic), which subscribers count as lost
        assert seqs[0] >= 1 and all(b > a for a, b in zip(seqs, seqs[1:])), key
        assert all(b > a for a, b in zip(stamps, stamps[1:])), key
    parsed = [names.parse_token(t) for t in tokens]
    assert {t.kind for t in parsed} == {"NN", "MP"}
    assert {f"0{t.topic}/{t.type_name}/{t.type_hash}" for t in parsed if t.kind == "MP"} >= set(per_key)
    with Store(out / "demo.db", readonly=True) as store:
        (run,) = store.runs()
        recorded = [a for a in store.attempts(run.run_id) if a.mcap]  # a retried attempt has its file too
        attempts = [a for a in recorded if a.status == "ok"]
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
    assert len(topics["/ubot1/joint_states"]) == sum(
        len(_topics(out / "mcap" / a.mcap)["/ubot1/joint_states"]) for a in recorded)
    assert topics["/ubot1/learner/updates"]
