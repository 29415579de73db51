"""The agent's ROS 2 bridge and MCAP episodes during real simulated episodes: real agent
service, simulated robot on a virtual bus, real Zenoh router, a zenoh-python subscriber on the
documented keys; every message decoded with rosbags' Jazzy typestore; the MCAP files read with
mcap + mcap-ros2-support and with rosbags."""
from __future__ import annotations

import os
import signal
import uuid
from collections import Counter, defaultdict

import can
import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.agent.telemetry import JOINTS
from ersac_hil.ros2 import names
from ersac_hil.ros2.options import Ros2Options
from ersac_hil.ros2.writer import NICE
from ersac_hil.zenoh_session import BURSTS, EmbeddedRouter
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.timing import PATIENCE_S
from helpers.waiting import wait_until
from protocol.can.busconfig import BusConfig
from protocol.can.devices import AGENT_NODE_ID
from protocol.robot import default_description
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

pytestmark = pytest.mark.timeout(240)
JAZZY = get_typestore(Stores.ROS2_JAZZY)
DOMAIN = 7
TOPICS = {"joint_states": "sensor_msgs/msg/JointState", "imu": "sensor_msgs/msg/Imu",
          "diagnostics": "diagnostic_msgs/msg/DiagnosticArray", "episode": "diagnostic_msgs/msg/DiagnosticStatus"}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two bracing episodes with --ros2 --ros-domain 7 --ros-namespace /lab/ubot1 --record;
    what a subscriber on ``7/**`` and ``@ros2_lv/7/**`` saw, the agent's own telemetry. The
    router shares this interpreter with the agent and the simulator, so its subscriber here is
    slow on a loaded machine: the router gets the burst settings (``BURSTS``) a recorder's
    router would, or its queue towards us drops live samples (rmw_zenoh's DROP)."""
    record = tmp_path_factory.mktemp("mcap")
    bus = BusConfig("virtual", f"ros2-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-ros")
    robot = SimulatedRobot(bus)
    samples, tokens, telemetry = [], {}, []
    try:
        with EmbeddedRouter(extra=BURSTS) as router:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,),
                                 ros2=Ros2Options(domain=DOMAIN, namespace="/lab/ubot1"), record=str(record))
            with router.open_client() as session:
                def on_token(sample):
                    tokens[str(sample.key_expr)] = sample.kind
                live = session.liveliness().declare_subscriber("@ros2_lv/7/**", on_token, history=True)
                sub = session.declare_subscriber(f"{DOMAIN}/**", lambda s: samples.append(
                    (str(s.key_expr), s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes())))
                with AgentService(config) as agent:
                    hook = agent.runner.observe
                    agent.runner.observe = lambda tel: (telemetry.append(tel), hook(tel))
                    wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                    wait_until(lambda: len(tokens) == 1 + len(TOPICS), what="the node's and publishers' tokens")
                    replies = []
                    for eid, theta in (("ep-r1", 0.3), ("ep-r2", 0.5)):
                        request = EpisodeRequest(eid, "bracing", (theta,), 5)
                        replies += [EpisodeResult.from_json(r.ok.payload) for r in
                                    session.get(keys.episode_run, payload=request.to_json(), timeout=90)]
                    n = sum(round(r.telemetry["n_cycles"]) for r in replies)
                    joint_states = lambda: sum(k.split("/")[3] == "joint_states" for k, _, _ in samples)  # noqa: E731
                    try:
                        wait_until(lambda: joint_states() >= n, what="every joint state")
                    except pytest.fail.Exception:
                        pytest.fail(f"{joint_states()} of {n} joint states arrived; the agent dropped {agent.feed.dropped}")
                    dropped = agent.feed.dropped
                    # each file appears under its name when complete, while the agent runs on
                    wait_until(lambda: all((record / r.mcap).is_file() for r in replies), what="the MCAP files")
                    summaries = []
                    for r in replies:
                        with open(record / r.mcap, "rb") as f:
                            summaries.append(make_reader(f).get_summary())
                    writer = agent.feed.process._proc
                    wait_until(lambda: os.getpriority(os.PRIO_PROCESS, writer.pid) >= min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICE),  # 19: the lowest
                               what="the feed process at a lower priority")
                    writer_scheduler = os.sched_getscheduler(writer.pid)
                assert writer.poll() == 0  # the agent's stop ended its feed process
                wait_until(lambda: all(kind == zenoh.SampleKind.DELETE for kind in tokens.values()), what="tokens withdrawn")
                sub.undeclare()
                live.undeclare()
    finally:
        robot.close()
    return dict(samples=samples, tokens=tokens, replies=replies, telemetry=telemetry, record=record,
                dropped=dropped, summaries=summaries, writer_scheduler=writer_scheduler)


def test_every_sample_is_on_a_documented_key_with_rosbags_hash_and_decodes(run):
    by_topic = defaultdict(list)
    for key, payload, _ in run["samples"]:
        domain, ns1, ns2, topic, dds, type_hash = key.split("/")
        assert (int(domain), ns1, ns2) == (DOMAIN, "lab", "ubot1")
        typename = names.ros_type(dds)
        assert typename == TOPICS[topic]
        assert type_hash == JAZZY.hash_rihs01(typename)
        by_topic[topic].append(JAZZY.deserialize_cdr(payload, typename))
    assert set(by_topic) == set(TOPICS)
    assert all(list(m.name) == list(JOINTS) for m in by_topic["joint_states"])
    episodes = [m for m in by_topic["episode"] if m.message != "started"]
    assert [m.hardware_id for m in episodes] == ["ep-r1", "ep-r2"]
    for msg, result, theta in zip(episodes, run["replies"], (0.3, 0.5)):
        values = {kv.key: kv.value for kv in msg.values}
        assert (values["status"], values["task"], float(values["theta_0"])) == (result.status, "bracing", theta)
        if result.ok:
            assert float(values["total_cost"]) == result.total_cost
            assert {k[5:] for k in values if k.startswith("cost.")} == set(result.cost_terms)
    assert any(s.name == "ubot-ros/wheels" for m in by_topic["diagnostics"] for s in m.status)


def test_the_joint_states_are_the_agents_telemetry(run):
    assert run["dropped"] == 0
    states = [JAZZY.deserialize_cdr(p, TOPICS["joint_states"]) for k, p, _ in run["samples"]
              if k.split("/")[3] == "joint_states"]
    assert len(states) == len(run["telemetry"])
    axes = [default_description().axis(j) for j in JOINTS]
    for msg, tel in zip(states, run["telemetry"]):
        assert tuple(msg.position) == tel.position and tuple(msg.velocity) == tel.velocity
        # effort of every axis: current x the description's torque constant x gear
        assert list(msg.effort) == [i * (a.torque_constant * a.gear) for i, a in zip(tel.current, axes)]


def test_attachments_carry_increasing_sequence_numbers_and_stamps(run):
    per_key = defaultdict(list)
    for key, _, attachment in run["samples"]:
        assert attachment is not None and len(attachment) == names.ATTACHMENT_SIZE
        per_key[key].append(names.parse_attachment(attachment))
    gids = set()
    for key, atts in per_key.items():
        seqs, stamps = [a[0] for a in atts], [a[1] for a in atts]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and seqs[0] == 1, key
        assert all(b > a for a, b in zip(stamps, stamps[1:])), key
        assert len({a[2] for a in atts}) == 1, key
        gids.add(atts[0][2])
    assert len(gids) == len(per_key)  # one GID per publisher


def test_the_tokens_parse_and_name_the_published_keys(run):
    parsed = [names.parse_token(k) for k in run["tokens"]]
    nodes = [t for t in parsed if t.kind == "NN"]
    assert [(n.domain, n.namespace, n.node) for n in nodes] == [(DOMAIN, "/lab/ubot1", "ersac_agent")]
    pubs = {t.topic: t for t in parsed if t.kind == "MP"}
    assert set(pubs) == {f"/lab/ubot1/{t}" for t in TOPICS}
    keys = {k for k, _, _ in run["samples"]}
    for topic, t in pubs.items():
        assert t.zid == nodes[0].zid and t.node_id == nodes[0].node_id
        assert f"{DOMAIN}{topic}/{t.type_name}/{t.type_hash}" in keys
    assert len({t.entity_id for t in pubs.values()}) == len(pubs)


def test_each_episode_is_one_mcap_file_that_mcap_and_rosbags_read(run):
    replies, record = run["replies"], run["record"]
    assert [r.mcap for r in replies] == ["ep-r1.mcap", "ep-r2.mcap"]
    n0 = round(replies[0].telemetry["n_cycles"])
    per_episode = [run["telemetry"][:n0], run["telemetry"][n0:]]
    for result, telemetry in zip(replies, per_episode):
        path = record / result.mcap
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            assert reader.get_header().profile == "ros2"
            got = defaultdict(list)
            for schema, channel, message, decoded in reader.iter_decoded_messages():
                assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
                got[channel.topic].append(decoded)
        states = got["/lab/ubot1/joint_states"]
        assert len(states) == len(telemetry) == round(result.telemetry["n_cycles"])
        for msg, tel in zip(states, telemetry):
            assert tuple(msg.position) == tel.position and tuple(msg.velocity) == tel.velocity
        assert len(got["/lab/ubot1/imu"]) == len(telemetry)
        # the agent's own bus: every SYNC it sent (one a cycle), its RPDOs and the TPDOs it received
        frames = got["/lab/ubot1/can"]
        counts = Counter(f.id for f in frames)
        assert counts[0x80] == counts[0x1A0] == len(telemetry)  # SYNCs sent, IMU TPDOs received
        assert any(0x701 <= cob_id <= 0x77F for cob_id in counts)  # the nodes' heartbeats
        assert len(frames) > 10 * len(telemetry)
        assert all(f.header.frame_id == "can" and 0 < f.dlc <= 8 for f in frames if f.id != 0x80)
        events = [e.message for e in got["/lab/ubot1/events"]]
        assert "started" in events[0] and "ended" in events[-1]
        with AnyReader([path]) as bag:
            conns = {c.topic: c for c in bag.connections}
            assert conns["/lab/ubot1/joint_states"].msgtype == "sensor_msgs/msg/JointState"
            js = [bag.deserialize(raw, c.msgtype) for c, _, raw in
                  bag.messages(connections=[conns["/lab/ubot1/joint_states"]])]
            assert np.array_equal([m.position for m in js], [t.position for t in telemetry])


def test_the_files_are_whole_under_their_names_and_nothing_is_left_half_written(run):
    assert run["writer_scheduler"] == os.SCHED_OTHER  # never real-time, even under a SCHED_FIFO agent
    assert all(summary is not None and summary.statistics.message_count > 0 for summary in run["summaries"])
    assert sorted(p.name for p in run["record"].iterdir()) == ["ep-r1.mcap", "ep-r2.mcap"]


def test_a_feed_that_falls_behind_drops_counts_and_reports(tmp_path, caplog):
    """A queue of 2 items cannot hold an episode's cycles and frames: what does not fit is
    dropped, counted, logged and written into the file's metadata; the file is still whole."""
    bus = BusConfig("virtual", f"ros2-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-drop")
    robot = SimulatedRobot(bus)
    try:
        with EmbeddedRouter() as router, router.open_client() as session:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,),
                                 ros2=Ros2Options(queue_size=2), record=str(tmp_path))
            with AgentService(config) as agent:
                wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                request = EpisodeRequest("ep-d1", "bracing", (0.5,), 5)
                [reply] = [EpisodeResult.from_json(r.ok.payload) for r in
                           session.get(keys.episode_run, payload=request.to_json(), timeout=90)]
                feed = agent.feed
                # the reply names the file at once; the feed process (niceness +10) renames it
                # when whole, and a stop gives a starved writer only 5 s
                wait_until(lambda: (tmp_path / reply.mcap).is_file(), PATIENCE_S * 6, what="the whole MCAP file")
    finally:
        robot.close()
    with open(tmp_path / reply.mcap, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert int(meta["feed"]["dropped_samples"]) > 0
    assert any("dropped" in r.getMessage() and "ep-d1" in r.getMessage() for r in caplog.records)
    assert feed.dropped == int(meta["feed"]["dropped_samples"])


def test_recording_without_the_bridge_encodes_every_cycle_in_the_writer_process(tmp_path):
    """``--record`` alone: no ROS 2 node, the feed process encodes each cycle's joint state
    and IMU from the telemetry itself."""
    bus = BusConfig("virtual", f"ros2-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-rec")
    robot, telemetry = SimulatedRobot(bus), []
    try:
        with EmbeddedRouter() as router, router.open_client() as session:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), record=str(tmp_path))
            with AgentService(config) as agent:
                assert list(session.liveliness().get("@ros2_lv/**", timeout=1)) == []  # no ROS 2 node
                hook = agent.runner.observe
                agent.runner.observe = lambda tel: (telemetry.append(tel), hook(tel))
                wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                request = EpisodeRequest("ep-o1", "bracing", (0.5,), 5)
                [reply] = [EpisodeResult.from_json(r.ok.payload) for r in
                           session.get(keys.episode_run, payload=request.to_json(), timeout=90)]
                wait_until(lambda: (tmp_path / reply.mcap).is_file(), what="the MCAP file, whole")
    finally:
        robot.close()
    got = defaultdict(list)
    with open(tmp_path / reply.mcap, "rb") as f:
        for _, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic].append(decoded)
    axes = [default_description().axis(j) for j in JOINTS]
    states = got["/ubot_rec/joint_states"]
    assert len(states) == len(got["/ubot_rec/imu"]) == len(telemetry) == round(reply.telemetry["n_cycles"])
    for msg, tel in zip(states, telemetry):
        assert tuple(msg.position) == tel.position and tuple(msg.velocity) == tel.velocity
        assert list(msg.effort) == [i * (a.torque_constant * a.gear) for i, a in zip(tel.current, axes)]
    assert [m.message for m in got["/ubot_rec/episode"]] == ["started", reply.status]


def test_the_recording_holds_every_frame_the_agent_sends_and_receives_in_order(tmp_path):
    """The ``can`` topic against a listener of its own on the bus: inside the episode, every
    frame on the bus is in the file (the agent's NMT commands, SDO requests, timer and SYNC
    heartbeats, RPDOs, SYNCs, and what the nodes sent) and nothing else; in log-time order
    each SYNC is followed by its cycle's TPDOs and each SDO answer follows its request."""
    bus = BusConfig("virtual", f"ros2-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-can")
    robot = SimulatedRobot(bus)
    heard: list = []
    listener = can.Bus(**bus.kwargs())
    notifier = can.Notifier(listener, [lambda msg: heard.append(msg)])
    try:
        with EmbeddedRouter() as router, router.open_client() as session:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), record=str(tmp_path))
            with AgentService(config):
                wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                request = EpisodeRequest("ep-c1", "bracing", (0.5,), 5)
                [reply] = [EpisodeResult.from_json(r.ok.payload) for r in
                           session.get(keys.episode_run, payload=request.to_json(), timeout=90)]
                wait_until(lambda: (tmp_path / reply.mcap).is_file(), PATIENCE_S * 6, what="the MCAP file, whole")
    finally:
        notifier.stop()
        listener.shutdown()
        robot.close()
    with open(tmp_path / reply.mcap, "rb") as f:
        recorded = [(message.log_time / 1e9, decoded) for _, channel, message, decoded in
                    make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/ubot_can/can"])]
    frames = [(t, f.id, bytes(f.data[:f.dlc])) for t, f in recorded]
    ids = [cob_id for _, cob_id, _ in frames]
    # the agent's own frames besides the cycles': NMT (pre-operational, start, pre-operational), SDO
    assert [data for _, cob_id, data in frames if cob_id == 0] == [b"\x80\x00", b"\x01\x00", b"\x80\x00"]
    requests = [cob_id for cob_id in ids if 0x601 <= cob_id <= 0x67F]
    assert requests and len(requests) == sum(0x581 <= cob_id <= 0x5FF for cob_id in ids)
    # in order: every SDO answer after an unanswered request of its node, one IMU TPDO after each SYNC
    unanswered = Counter()
    for cob_id in ids:
        if 0x601 <= cob_id <= 0x67F:
            unanswered[cob_id - 0x600] += 1
        elif 0x581 <= cob_id <= 0x5FF:
            assert unanswered[cob_id - 0x580] > 0, hex(cob_id)
            unanswered[cob_id - 0x580] -= 1
    cyclic = [cob_id for cob_id in ids if cob_id in (0x80, 0x1A0)]
    assert cyclic == [0x80, 0x1A0] * round(reply.telemetry["n_cycles"])
    # everything on the bus inside the episode, and nothing else (multisets; a margin at the
    # edges, where the two clocks' stamps of one frame may straddle the window)
    first, last, margin = frames[0][0], frames[-1][0], 0.02
    on_bus = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in heard]

    def inside(seq, lo, hi):
        return Counter((cob_id, data) for t, cob_id, data in seq if lo <= t <= hi)
    lo, hi = first + margin, last - margin
    assert not inside(on_bus, lo, hi) - inside(frames, lo - margin, hi + margin)
    assert not inside(frames, lo, hi) - inside(on_bus, lo - margin, hi + margin)
    # the agent's heartbeats: with each 20th SYNC in lock-step, and those of its timer
    assert ids.count(0x700 + AGENT_NODE_ID) > round(reply.telemetry["n_cycles"]) // 20


def test_a_stalled_writer_process_does_not_hold_up_the_agents_stop(tmp_path, caplog):
    """The feed process stopped (SIGSTOP) during an episode: the reply still comes, the
    agent's stop ends the process after its grace time (SIGKILL: a stopped process cannot act
    on SIGTERM), no process is left, there is no half-written file under the episode's name,
    and the agent says which file stays ``.part``."""
    bus = BusConfig("virtual", f"ros2-{uuid.uuid4().hex[:8]}")
    keys = KeySpace("ubot-stall")
    robot = SimulatedRobot(bus)
    try:
        with EmbeddedRouter() as router, router.open_client() as session:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), record=str(tmp_path))
            with AgentService(config) as agent:
                writer = agent.feed.process._proc
                wait_until(lambda: list(session.liveliness().get(keys.agent_alive, timeout=1)))
                os.kill(writer.pid, signal.SIGSTOP)
                request = EpisodeRequest("ep-s1", "bracing", (0.5,), 5)
                [reply] = [EpisodeResult.from_json(r.ok.payload) for r in
                           session.get(keys.episode_run, payload=request.to_json(), timeout=90)]
                assert reply.mcap == "ep-s1.mcap"
    finally:
        robot.close()
    assert writer.poll() is not None
    assert not (tmp_path / "ep-s1.mcap").exists()  # at most ep-s1.mcap.part, as far as it got
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING" and "not finished" in r.getMessage()]
    part = (tmp_path / "ep-s1.mcap.part").exists()
    assert len(said) == 1 and ("ep-s1.mcap.part left" if part else "ep-s1.mcap never begun") in said[0]


def test_report_exports_a_run_with_every_episode_and_the_updates(run, tmp_path):
    """The daemon's store of these episodes (schema with the MCAP name), exported by
    ``ersac-hil report RUN --mcap FILE --mcap-dir DIR`` into one file."""
    from ersac_hil.cli import main
    from ersac_hil.daemon.store import Store, UpdateRecord

    replies, db = run["replies"], tmp_path / "ersac.db"
    with Store(db) as store:
        store.create_run("run1", "ubot-ros", "bracing", 5, {"theta0": [0.3]})
        for i, (result, theta) in enumerate(zip(replies, (0.3, 0.5))):
            store.begin_attempt("run1", result.episode_id, i, 0, (theta,), (0.0,), (theta,), 5)
            update = UpdateRecord("run1", i, result.episode_id, (theta,), (theta + 0.1,), 1.0, None, None,
                                  None, None, 1.0, 0.1, {}, 1000.0 + i)
            if result.ok:
                store.record_success(result.episode_id, result, result.total_cost, update)
            else:
                store.record_failure(result.episode_id, result.status, result.detail, result)
        store.begin_attempt("run1", "run1.lost", 2, 0, (0.4,), (0.0,), (0.4,), 6)
        store.record_failure("run1.lost", "timeout", "no reply")
        assert [e.mcap for e in store.attempts("run1")] == ["ep-r1.mcap", "ep-r2.mcap", ""]
        n_updates = len(store.updates("run1"))
    out = tmp_path / "run1.mcap"
    assert main(["report", "run1", "--db", str(db), "--mcap", str(out), "--mcap-dir", str(run["record"])]) == 0
    got = defaultdict(list)
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for _, channel, _, decoded in reader.iter_decoded_messages():
            got[channel.topic].append(decoded)
    assert [m.hardware_id for m in got["/ubot_ros/episode"]] == ["ep-r1", "ep-r2", "run1.lost"]
    assert got["/ubot_ros/episode"][-1].message == "timeout"
    assert len(got["/ubot_ros/learner/updates"]) == n_updates
    assert len(got["/lab/ubot1/joint_states"]) == len(run["telemetry"])  # every cycle of both episodes
    starts = [e.message for e in got["/lab/ubot1/events"] if "started" in e.message]
    assert [s.split()[1] for s in starts] == ["ep-r1", "ep-r2"]


def test_report_mcap_refusals_write_nothing(tmp_path, capsys):
    from ersac_hil.cli import main
    from ersac_hil.daemon.store import Store
    db = tmp_path / "ersac.db"
    with Store(db) as store:
        store.create_run("run1", "ubot1", "bracing", 5, {"theta0": [0.3]})
    before = sorted(tmp_path.iterdir())
    for argv, why in ((["--mcap", str(tmp_path / "no" / "x.mcap")], "--mcap: no directory"),
                      (["--mcap", str(tmp_path / "x.mcap"), "--mcap-dir", str(tmp_path / "nowhere")], "--mcap-dir"),
                      (["--mcap-dir", str(tmp_path)], "--mcap-dir needs --mcap")):
        assert main(["report", "run1", "--db", str(db), *argv]) == 2
        assert why in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == before
