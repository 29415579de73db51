"""The learner's control plane over a real Zenoh router with real client sessions.

One daemon learns a short run against the synthetic agent and then lingers; every test talks
to it as a client would (queries with selectors, raw puts) and checks both the replies and
the store. Invalid requests, including hypothesis-generated garbage, must be refused and
change nothing.
"""
from __future__ import annotations

import json
import queue
import threading

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.daemon.clients import LearnerClient, NoAnswer, RequestRefused
from ersac_hil.daemon.config import DaemonConfig
from ersac_hil.daemon.service import Daemon
from ersac_hil.daemon.store import Store
from helpers.synthetic_agent import SyntheticAgent
from helpers.waiting import wait_until
from protocol.zenoh import (
    CriticQuery,
    CriticReply,
    ErrorReply,
    KappaCommand,
    KeySpace,
    LearnerEpisode,
    LearnerState,
    SelectQuery,
    SelectReply,
    WeightsCommand,
)

ROBOT = "ctl"
KS = KeySpace(ROBOT)
EPISODES = 14


@pytest.fixture(scope="module")
def learned(router, tmp_path_factory):
    """A daemon that learned EPISODES episodes and lingers, its agent, a monitor session
    recording learner/episodes and learner/error, and the store path."""
    db = tmp_path_factory.mktemp("ctl") / "ctl.db"
    agent_session = router.open_client()
    agent = SyntheticAgent(agent_session, KS, fault_every=4)
    monitor = router.open_client()
    episodes: list[LearnerEpisode] = []
    errors: queue.Queue[ErrorReply] = queue.Queue()
    subs = [
        monitor.declare_subscriber(KS.learner_episodes,
                                   lambda s: episodes.append(LearnerEpisode.from_json(s.payload))),
        monitor.declare_subscriber(KS.learner_error, lambda s: errors.put(ErrorReply.from_json(s.payload))),
    ]
    config = DaemonConfig(robot=ROBOT, zenoh=(router.endpoint,), db=db, seed=5, episodes=EPISODES,
                          kappa=1.0, resume="new", linger=True, backoff_s=(0.05, 0.1))
    daemon = Daemon(config)
    daemon.start()
    wait_until(lambda: daemon.handlers.state().status == "idle")
    yield {"daemon": daemon, "db": db, "episodes": episodes, "errors": errors, "monitor": monitor,
           "agent": agent}
    daemon.stop()
    for sub in subs:
        sub.undeclare()
    monitor.close()
    agent.close()
    agent_session.close()


@pytest.fixture
def client(router):
    with LearnerClient(KS, [router.endpoint], timeout_s=20.0) as c:
        yield c


def _get(session: zenoh.Session, selector: str, payload: bytes | None = None):
    replies = list(session.get(selector, payload=payload, timeout=20.0))
    assert len(replies) == 1
    return replies[0]


def _refused(session: zenoh.Session, selector: str, payload: bytes | None = None) -> ErrorReply:
    reply = _get(session, selector, payload)
    assert reply.ok is None, f"{selector} was accepted"
    return ErrorReply.from_json(reply.err.payload)


def _snapshot(learned) -> tuple:
    """Everything a refused request must leave alone: learner state and the store."""
    daemon = learned["daemon"]
    with Store(learned["db"], readonly=True) as store:
        run = daemon.learning.run_id
        return (daemon.handlers.state(), [(e.episode_id, e.cost) for e in store.attempts(run)],
                store.changes(run), len(store.updates(run)))


def _drain(errors: queue.Queue) -> list[ErrorReply]:
    out = []
    while True:
        try:
            out.append(errors.get_nowait())
        except queue.Empty:
            return out


# --------------------------------------------------------------------------- queries
def test_state_and_published_episodes(learned, client):
    state = client.state()
    assert isinstance(state, LearnerState)
    assert state.run_id == learned["daemon"].learning.run_id and state.task == "bracing"
    assert state.episode_count == EPISODES and state.status == "idle" and state.kappa == 1.0
    with Store(learned["db"], readonly=True) as store:
        attempts = store.attempts(state.run_id)
        ok = store.ok_episodes(state.run_id)
    assert [e.idx for e in ok] == list(range(EPISODES))
    faults = [a for a in attempts if a.status == "fault_pdo_timeout"]
    assert faults, "the synthetic agent injects faults; they must be recorded"
    published = wait_until(lambda: len(learned["episodes"]) >= len(attempts) and learned["episodes"])
    assert [p.request.episode_id for p in published] == [a.episode_id for a in attempts]
    by_id = {a.episode_id: a for a in attempts}
    for p in published:
        a = by_id[p.request.episode_id]
        assert p.index == a.idx and p.result.status == a.status and p.cost == a.cost
        assert p.request.theta == a.theta and p.request.seed == a.seed


def test_history_is_what_was_published(learned, client):
    """A late client asks ``learner/episodes`` for the run so far: every attempt the agent
    answered, in recording order, as published (the cost under the learner's current weights)."""
    with Store(learned["db"], readonly=True) as store:
        attempts = len(store.attempts(client.state().run_id))
    published = wait_until(lambda: len(learned["episodes"]) >= attempts and learned["episodes"])
    history = client.episodes()
    assert [h.result.episode_id for h in history] == [p.result.episode_id for p in published]
    engine = learned["daemon"].learning.engine
    for h, p in zip(history, published):
        assert (h.run_id, h.index, h.base_theta, h.z, h.request) == (p.run_id, p.index, p.base_theta, p.z, p.request)
        assert h.result == p.result
        assert h.cost == (engine.cost(h.result.cost_terms) if h.result.ok else None)


def test_critic_points_and_grid(learned, client):
    theta = learned["daemon"].handlers.state().theta
    reply = client.critic(CriticQuery((theta, (0.25,)), kappa=2.0))
    assert isinstance(reply, CriticReply) and reply.kappa == 2.0
    assert [p.theta for p in reply.points] == [theta, (0.25,)]
    for p in reply.points:
        assert p.r >= 0 and p.F == pytest.approx(p.J + 2.0 * p.r)
    grid = client.critic(CriticQuery(grid=11))
    assert [p.theta[0] for p in grid.points] == pytest.approx([i / 10 for i in range(11)])
    assert grid.kappa == 1.0  # the learner's kappa when none is given
    # the same point twice gives the same answer (no state changed by a query)
    again = client.critic(CriticQuery((theta,), kappa=2.0))
    assert again.points[0] == reply.points[0]


def test_select_without_and_with_adopt(learned, client):
    daemon = learned["daemon"]
    before = client.state()
    sel = client.select(SelectQuery(kappa=0.0))
    assert isinstance(sel, SelectReply) and not sel.adopted
    assert sel.F == pytest.approx(sel.J) and sel.kappa == 0.0
    assert client.state().theta == before.theta
    with Store(learned["db"], readonly=True) as store:
        # the default bracing learner's own final selection is the only theta change
        assert [c.source for c in store.changes(daemon.learning.run_id, "theta")] == ["final selection"]
    risky = client.select(SelectQuery(kappa=3.0, weights={"damage": 50.0}, adopt=True))
    assert risky.adopted and risky.weights["damage"] == 50.0
    assert risky.weights["body_acc_sq"] == before.weights["body_acc_sq"]
    after = client.state()
    assert after.theta == risky.theta
    assert after.weights == before.weights  # selection weights are not adopted
    with Store(learned["db"], readonly=True) as store:
        change = store.latest_change(daemon.learning.run_id, "theta")
        assert tuple(change.value) == risky.theta and change.n_updates == EPISODES


def test_kappa_put_is_applied_and_recorded(learned, client):
    daemon = learned["daemon"]
    state = client.set_kappa(2.5)
    assert state.kappa == 2.5 and daemon.learning.engine.kappa == 2.5
    with Store(learned["db"], readonly=True) as store:
        change = store.latest_change(daemon.learning.run_id, "kappa")
    assert change.value == 2.5 and change.source == "control" and change.n_updates == EPISODES
    assert client.critic(CriticQuery(((0.5,),))).kappa == 2.5
    client.set_kappa(1.0)


def test_weights_put_recosts_every_stored_episode(learned, client):
    daemon = learned["daemon"]
    new = {"damage": 40.0, "arm_power": 0.5}
    state = client.set_weights(new)
    assert state.weights["damage"] == 40.0 and state.weights["arm_power"] == 0.5
    assert state.weights["body_acc_sq"] == 0.1
    complete = dict(state.weights)
    with Store(learned["db"], readonly=True) as store:
        run = daemon.learning.run_id
        change = store.latest_change(run, "weights")
        ok = store.ok_episodes(run)
        updates = store.updates(run)
    assert change.value == complete and change.n_updates == EPISODES
    for ep in ok:
        expected = daemon.learning.engine.cost(ep.cost_terms)
        assert ep.cost == expected  # exactly the learner's own cost under the new weights
        assert expected == pytest.approx(sum(complete[k] * ep.cost_terms[k] for k in complete))
    assert [u.cost for u in updates] != [ep.cost for ep in ok]  # history keeps what was told
    client.set_weights({"damage": 10.0, "arm_power": 5.0})


# --------------------------------------------------------------------------- refusals
BAD_QUERIES = [
    ("critic", "theta=1.5", "theta[0][0]"),            # outside the task box
    ("critic", "theta=0.1,0.2", "theta[0]"),           # wrong dimension
    ("critic", "theta=abc", "theta[0][0]"),
    ("critic", "theta=nan", "theta[0][0]"),
    ("critic", "grid=1", "grid"),
    ("critic", "grid=5;theta=0.5", "theta"),
    ("critic", "", "theta"),
    ("critic", "colour=blue", "colour"),
    ("critic", "theta=0.5;kappa=99", "kappa"),
    ("select", "", "kappa"),
    ("select", "kappa=11", "kappa"),
    ("select", "kappa=1;weights=bogus:1", "bogus"),
    ("select", "kappa=1;weights=damage:-1", "damage"),
    ("select", "kappa=1;adopt=maybe", "adopt"),
    ("select", "kappa=1;weights=body_acc_sq:1e308", "within [0, 1e+06]"),
    ("select", "kappa=1;weights=body_acc_sq:1e300", "within [0, 1e+06]"),
    ("state", "verbose=1", "verbose"),
    ("episodes", "since=3", "since"),
]


@pytest.mark.parametrize(("kind", "params", "mentions"), BAD_QUERIES)
def test_invalid_queries_are_refused_and_change_nothing(learned, kind, params, mentions):
    session = learned["monitor"]
    before = _snapshot(learned)
    key = {"critic": KS.learner_critic, "select": KS.learner_select, "state": KS.learner_state,
           "episodes": KS.learner_episodes}[kind]
    error = _refused(session, KS.selector(key, params or None))
    assert error.code == "invalid_request" and mentions in error.reason
    assert _snapshot(learned) == before


def test_query_payloads_are_refused(learned):
    session = learned["monitor"]
    before = _snapshot(learned)
    error = _refused(session, KS.learner_state, payload=b'{"v": 1}')
    assert error.code == "invalid_request" and "payload" in error.reason
    assert _snapshot(learned) == before


BAD_PUTS = [
    ("kappa", b"", "not valid JSON"),
    ("kappa", b"2.0", "JSON object"),
    ("kappa", KappaCommand(1.0).to_json().replace(b"1.0", b"11.0"), "kappa"),
    ("kappa", b'{"v": 1, "type": "kappa_command", "kappa": NaN}', "NaN"),
    ("kappa", b'{"v": 2, "type": "kappa_command", "kappa": 1.0}', "version"),
    ("kappa", WeightsCommand({"damage": 1.0}).to_json(), "type"),
    ("weights", WeightsCommand({"gravity": 1.0}).to_json(), "gravity"),  # not a bracing term
    ("weights", b'{"v": 1, "type": "weights_command", "weights": {}}', "empty"),
    ("weights", b'{"v": 1, "type": "weights_command", "weights": {"damage": -3}}', "minimum"),
    ("weights", b"\xff\xfe", "UTF-8"),
    ("weights", WeightsCommand({"body_acc_sq": 1e308}).to_json(), "within [0, 1e+06]"),
    ("weights", WeightsCommand({"body_acc_sq": 1e300}).to_json(), "within [0, 1e+06]"),  # crashed the daemon once
]


@pytest.mark.parametrize(("kind", "payload", "mentions"), BAD_PUTS)
def test_invalid_puts_are_refused_published_and_change_nothing(learned, kind, payload, mentions):
    session, errors = learned["monitor"], learned["errors"]
    _drain(errors)
    before = _snapshot(learned)
    key = KS.learner_kappa if kind == "kappa" else KS.learner_weights
    session.put(key, payload)
    error = errors.get(timeout=20.0)
    assert error.code == "invalid_request" and error.reason.startswith(f"learner/{kind}:")
    assert mentions in error.reason
    learned["daemon"].control.drain()
    assert _snapshot(learned) == before


def test_delete_on_a_command_key_is_refused(learned):
    session, errors = learned["monitor"], learned["errors"]
    _drain(errors)
    before = _snapshot(learned)
    session.delete(KS.learner_kappa)
    assert "delete" in errors.get(timeout=20.0).reason
    assert _snapshot(learned) == before


_json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=10),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12)
_near_valid = st.builds(
    lambda kind, extra: json.dumps({"v": 1, "type": kind, **extra}).encode(),
    st.sampled_from(["kappa_command", "weights_command", "error", "learner_state"]),
    st.dictionaries(st.sampled_from(["kappa", "weights", "v", "x"]), _json_values, max_size=3))
_garbage = st.one_of(
    st.binary(max_size=64),
    _json_values.map(lambda v: json.dumps(v).encode()),
    _near_valid,
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(["kappa", "weights"]), payload=_garbage)
def test_garbage_puts_never_change_anything(learned, kind, payload):
    daemon = learned["daemon"]
    session, errors = learned["monitor"], learned["errors"]
    before = _snapshot(learned)
    _drain(errors)
    session.put(KS.learner_kappa if kind == "kappa" else KS.learner_weights, payload)
    # processed when refused (an error is published) or applied (every applied command is
    # recorded in the store, so the snapshot changes)
    wait_until(lambda: not errors.empty() or _snapshot(learned) != before, timeout_s=20.0)
    daemon.control.drain()
    after = _snapshot(learned)
    refused = _drain(errors)
    if after != before:
        # only a well-formed command may change something, and then it is exactly that change
        cmd = (KappaCommand if kind == "kappa" else WeightsCommand).from_json(payload)
        assert not refused
        if kind == "kappa":
            assert after[0].kappa == cmd.kappa
            daemon.handlers.set_kappa(KappaCommand(before[0].kappa))
        else:
            assert all(after[0].weights[k] == v for k, v in cmd.weights.items())
            daemon.handlers.set_weights(WeightsCommand(dict(before[0].weights)))
    else:
        assert refused


_param_text = st.text(alphabet="abcdefghikmnopqrstuvwxyz0123456789.,|;:=-+eE_ ", max_size=40)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(["critic", "select"]), params=_param_text)
def test_garbage_selectors_are_answered_and_change_nothing(learned, kind, params):
    session = learned["monitor"]
    before = _snapshot(learned)
    key = KS.learner_critic if kind == "critic" else KS.learner_select
    params = params.replace("adopt", "adapt")  # an adopt=true would legitimately change theta
    reply = _get(session, f"{key}?{params}" if params else key)
    if reply.ok is None:
        assert ErrorReply.from_json(reply.err.payload).code in ("invalid_request", "unavailable")
    else:
        (CriticReply if kind == "critic" else SelectReply).from_json(reply.ok.payload)
    assert _snapshot(learned) == before


# --------------------------------------------------------------------------- availability
def test_no_data_and_no_learner(router, daemon_factory):
    # a daemon whose agent never comes: the control plane works, the critic has no data
    daemon = daemon_factory("lonely", episodes=3)
    with LearnerClient(KeySpace("lonely"), [router.endpoint], timeout_s=10.0) as c:
        state = wait_until(lambda: c.state().status == "paused" and c.state())
        assert state.episode_count == 0
        with pytest.raises(RequestRefused) as err:
            c.critic(CriticQuery(((0.5,),)))
        assert err.value.error.code == "unavailable"
        with pytest.raises(RequestRefused) as err:
            c.select(SelectQuery(kappa=1.0))
        assert err.value.error.code == "unavailable"
    daemon.stop()
    with LearnerClient(KeySpace("nobody"), [router.endpoint], timeout_s=0.5) as c:
        with pytest.raises(NoAnswer):
            c.state()


def test_clients_refuse_invalid_values_locally(client):
    with pytest.raises(ValueError):
        client.set_kappa(float("nan"))
    with pytest.raises(ValueError):
        client.set_weights({})


def test_control_plane_serves_while_learning(router, agent_factory, daemon_factory):
    agent_factory("busy", delay_s=0.05)
    daemon = daemon_factory("busy", episodes=200)  # outlasts the asking below (stopped at teardown)
    answers = []

    def first_answer(c: LearnerClient) -> bool:
        try:  # the daemon's queryable reaches the router a moment after start() returned
            return c.state(timeout_s=1.0) is not None
        except NoAnswer:
            return False

    def ask() -> None:
        with LearnerClient(KeySpace("busy"), [router.endpoint], timeout_s=20.0) as c:
            wait_until(lambda: first_answer(c), what="the learner's first answer")
            while not daemon.finished.is_set() and len(answers) < 20:
                answers.append(c.state().episode_count)

    thread = threading.Thread(target=ask)
    thread.start()
    thread.join(60)
    assert len(answers) >= 5 and answers == sorted(answers) and not daemon.finished.is_set()


# --------------------------------------------------------------------------- CLI clients
def _cli(router, capsys, *argv: str) -> tuple[int, str, str]:
    from ersac_hil.cli import main
    code = main([*argv[:1], *argv[1:], "--robot", ROBOT, "--zenoh", router.endpoint, "--timeout", "20"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_clients(learned, router, capsys):
    code, out, _ = _cli(router, capsys, "state")
    assert code == 0 and f"run       {learned['daemon'].learning.run_id}" in out
    code, out, _ = _cli(router, capsys, "state", "--json")
    assert code == 0 and LearnerState.from_json(out.strip()).episode_count == EPISODES
    code, out, _ = _cli(router, capsys, "kappa", "set", "0.75")
    assert code == 0 and "kappa     0.75" in out
    code, out, _ = _cli(router, capsys, "kappa", "get")
    assert code == 0 and out.strip() == "0.75"
    code, out, _ = _cli(router, capsys, "critic", "--theta", "0.3", "--theta", "0.6", "--json")
    reply = CriticReply.from_json(out.strip())
    assert code == 0 and [p.theta for p in reply.points] == [(0.3,), (0.6,)] and reply.kappa == 0.75
    code, out, _ = _cli(router, capsys, "select", "--kappa", "1", "--weight", "damage=15")
    assert code == 0 and "selected theta" in out and "adopted False" in out
    code, out, _ = _cli(router, capsys, "weights", "get")
    assert code == 0 and json.loads(out)["damage"] == 10.0
    # refusals: by the learner (exit 1) and locally (exit 2); nothing changes
    before = _snapshot(learned)
    code, _, err = _cli(router, capsys, "critic", "--theta", "1.5")
    assert code == 1 and "invalid_request" in err and "theta[0][0]" in err
    code, _, err = _cli(router, capsys, "kappa", "set", "12")
    assert code == 2 and "kappa" in err
    code, _, err = _cli(router, capsys, "weights", "set", "gravity=1")  # no task's term
    assert code == 2 and "gravity" in err
    code, _, err = _cli(router, capsys, "weights", "set", "h_error_sq=1")  # lifting's, not bracing's
    assert code == 1 and "h_error_sq" in err
    assert _snapshot(learned) == before
    _cli(router, capsys, "kappa", "set", "1")
