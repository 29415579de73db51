"""The dashboard's server against a real learner: a real daemon learning from the synthetic
agent (the real protocol on a real Zenoh router), the dashboard in this process on a free port,
talked to over HTTP and server-sent events as a browser would."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from helpers.synthetic_agent import SyntheticAgent
from helpers.waiting import wait_until
from helpers.webclient import EventStream, http
from ersac_hil.daemon.clients import LearnerClient
from ersac_hil.daemon.config import DaemonConfig
from ersac_hil.daemon.service import Daemon
from ersac_hil.daemon.store import Store
from ersac_hil.dashboard.cli import DashboardService
from ersac_hil.zenoh_session import EmbeddedRouter, ZenohOptions
from protocol.zenoh import KeySpace, LearnerEpisode, get_task

ROOT = Path(__file__).resolve().parents[3]

ROBOT = "dash"
KS = KeySpace(ROBOT)
EPISODES = 10


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """Router, dashboard (with an event stream open from the start), synthetic agent, a monitor
    of learner/episodes, a daemon that learns EPISODES episodes and lingers, and a second
    dashboard started once three episodes were published."""
    db = tmp_path_factory.mktemp("dash") / "dash.db"
    with EmbeddedRouter() as router:
        dashboard = DashboardService(ROBOT, "ersac", ZenohOptions((router.endpoint,)), "127.0.0.1", 0,
                                     critic_points=11)
        dashboard.start()
        url = dashboard.server.url
        stream = EventStream(url)
        agent_session, monitor = router.open_client(), router.open_client()
        agent = SyntheticAgent(agent_session, KS, delay_s=0.02, fault_every=4)
        published: list[LearnerEpisode] = []
        sub = monitor.declare_subscriber(KS.learner_episodes,
                                         lambda s: published.append(LearnerEpisode.from_json(s.payload)))
        daemon = Daemon(DaemonConfig(robot=ROBOT, zenoh=(router.endpoint,), db=db, seed=5, episodes=EPISODES,
                                     kappa=1.0, resume="new", linger=True, backoff_s=(0.05, 0.1)))
        daemon.start()
        learner = LearnerClient(KS, [router.endpoint], timeout_s=20.0)
        late = DashboardService(ROBOT, "ersac", ZenohOptions((router.endpoint,)), "127.0.0.1", 0,
                                critic_points=11)
        try:
            wait_until(lambda: len(published) >= 3, what="three episodes")
            late.start()
            wait_until(lambda: learner.state().status == "idle", what="the run")
            yield {"url": url, "stream": stream, "learner": learner, "published": published, "db": db,
                   "endpoint": router.endpoint, "dashboard": dashboard, "late": late}
        finally:
            late.stop()
            learner.close()
            daemon.stop()
            sub.undeclare()
            agent.close()
            for session in (agent_session, monitor):
                session.close()
            stream.close()
            dashboard.stop()


def test_every_published_episode_reaches_the_page_in_order(stack):
    stream, published = stack["stream"], stack["published"]
    assert stream.events[0][0] == "snapshot"
    ids = lambda: [e.result.episode_id for e in published]  # noqa: E731
    wait_until(lambda: [d["point"]["episode_id"] for d in stream.of("episode")] == ids(), what="all episodes")
    points = [d["point"] for d in stream.of("episode")]
    assert sum(p["status"] == "ok" for p in points) == EPISODES
    assert any(p["status"] != "ok" and p["cost"] is None for p in points)  # fault_every=4
    for point, episode in zip(points, published):
        assert point["cost"] == episode.cost and point["theta"] == list(episode.request.theta)
    seqs = [d["seq"] for _, d in stream.events[1:]]
    assert seqs == sorted(set(seqs))
    wait_until(lambda: any(d["state"] and d["state"]["episode_count"] == EPISODES and d["state"]["status"] == "idle"
                           for d in stream.of("state")), what="final state")
    critic = wait_until(lambda: [d["critic"] for d in stream.of("critic") if d["critic"]
                                 and d["critic"]["episode_count"] == EPISODES], what="critic after the last update")
    (slice_,) = critic[-1]["slices"]
    assert len(slice_["x"]) == 11 and slice_["at"] == stack["learner"].state().theta[0]
    assert len(slice_["obs_x"]) == EPISODES
    fault = wait_until(lambda: stream.of("fault"))
    assert "fault_pdo_timeout" in fault[-1]["last_fault"]
    snapshot = http(stack["url"] + "api/snapshot")[1]
    assert [p["episode_id"] for p in snapshot["points"]] == ids() and snapshot["agent_alive"] is True


def test_a_dashboard_started_late_shows_the_whole_run_once(stack):
    published, late = stack["published"], stack["late"].server.url
    ids = lambda: [e.result.episode_id for e in published]  # noqa: E731
    wait_until(lambda: [p["episode_id"] for p in http(late + "api/snapshot")[1]["points"]] == ids(),
               what="every episode on the late dashboard, once, in order")
    points = http(late + "api/snapshot")[1]["points"]
    assert [p["seq"] for p in points] == list(range(len(points)))
    assert [(p["index"], p["status"], p["theta"]) for p in points] == \
        [(e.index, e.result.status, list(e.request.theta)) for e in published]


def test_api_state_is_what_the_cli_prints(stack):
    cli = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "state", "--robot", ROBOT, "--json",
                          "--zenoh", stack["endpoint"]], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert cli.returncode == 0, cli.stderr
    status, state = http(stack["url"] + "api/state")
    assert status == 200 and state == json.loads(cli.stdout)


def test_kappa_control_changes_the_learner_and_refuses_bad_input(stack):
    learner, url = stack["learner"], stack["url"]
    before = learner.state().kappa
    for body, raw, ctype, code in (({"kappa": 10.5}, None, "application/json", 400),
                                   ({"kappa": "2"}, None, "application/json", 400),
                                   ({"kappa": 2, "now": True}, None, "application/json", 400),
                                   (None, b'{"kappa": NaN}', "application/json", 400),
                                   ({"kappa": 2}, None, "text/plain", 415)):
        status, reply = http(url + "api/kappa", body, raw=raw, content_type=ctype)
        assert status == code and reply["error"]["reason"], reply
    assert learner.state().kappa == before
    status, reply = http(url + "api/kappa", {"kappa": -0.75})
    assert status == 200 and reply["type"] == "learner_state" and reply["kappa"] == -0.75
    assert learner.state().kappa == -0.75
    wait_until(lambda: any([EPISODES, -0.75] in d["kappa_marks"] for d in stack["stream"].of("state")),
               what="kappa mark")


def test_weights_control_recosts_the_curve_like_the_learner(stack):
    learner, url = stack["learner"], stack["url"]
    status, reply = http(url + "api/weights", {"weights": {"energy": 1.0}})
    assert status == 400 and reply["error"]["field"] == "weights.energy"
    status, reply = http(url + "api/weights", {"weights": {"arm_power": 50.0}})
    assert status == 200 and reply["weights"]["arm_power"] == 50.0
    assert learner.state().weights["arm_power"] == 50.0
    curve = wait_until(lambda: [d for d in stack["stream"].of("curve") if d["points"]], what="re-costed curve")
    with Store(stack["db"], readonly=True) as store:
        (run,) = store.runs()
        costs = {e.episode_id: e.cost for e in store.ok_episodes(run.run_id)}
    shown = {p["episode_id"]: p["cost"] for p in curve[-1]["points"] if p["cost"] is not None}
    assert shown == pytest.approx(costs)


def test_select_shows_then_adopt_changes_theta(stack):
    learner, url = stack["learner"], stack["url"]
    theta = learner.state().theta
    status, selected = http(url + "api/select", {"kappa": 3.0})
    assert status == 200 and selected["adopted"] is False and learner.state().theta == theta
    assert selected["F"] == pytest.approx(selected["J"] + 3.0 * selected["r"])
    status, adopted = http(url + "api/adopt", {"kappa": 3.0})
    assert status == 200 and adopted["adopted"] is True
    assert list(learner.state().theta) == adopted["theta"]
    get_task("bracing").check_theta(adopted["theta"])
    status, reply = http(url + "api/select", {"kappa": 3.0, "weights": {"nope": 1}})
    assert status == 400 and "nope" in reply["error"]["reason"]


def test_foreign_host_header_is_refused(stack):
    status, _ = http(stack["url"] + "api/state", headers={"Host": "attacker.example"})
    assert status == 400


def test_read_only_dashboard_shows_no_controls_and_forbids_them(stack):
    learner = stack["learner"]
    observer = DashboardService(ROBOT, "ersac", ZenohOptions((stack["endpoint"],)), "127.0.0.1", 0,
                                read_only=True)
    observer.start()
    url = observer.server.url
    try:
        stream = EventStream(url)
        status, page = http(url)
        assert status == 200 and 'id="controls"' not in page and "<input" not in page
        before = learner.state()
        for path, body in (("api/kappa", {"kappa": 0.1}), ("api/weights", {"weights": {"damage": 1.0}}),
                           ("api/select", {"kappa": 0.1}), ("api/adopt", {"kappa": 0.1})):
            status, reply = http(url + path, body)
            assert status == 403 and reply["error"]["code"] == "forbidden"
        assert learner.state() == before
        assert http(url + "api/state")[0] == 200
        snapshot = wait_until(lambda: stream.of("snapshot"))[0]
        assert snapshot["read_only"] is True
    finally:
        observer.stop()
    wait_until(lambda: stream.ended, what="the event stream to end on stop")
    stream.close()
    with pytest.raises(OSError):
        socket.create_connection((urlsplit(url).hostname, urlsplit(url).port), timeout=5).close()
