"""The dashboard's pure model: messages in, page events and snapshots out."""
from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.dashboard.model import DashboardModel, critic_query, critic_view
from protocol.zenoh import (
    TASKS,
    CriticPoint,
    CriticReply,
    EpisodeRequest,
    EpisodeResult,
    LearnerEpisode,
    LearnerState,
    get_task,
)

BRACING = get_task("bracing")
RUN = "run-1"


def _theta(spec, draw_fraction):  # noqa: ANN001
    return tuple(lo + (hi - lo) * f for lo, hi, f in zip(spec.lower, spec.upper, draw_fraction))


def state(kappa: float = 1.0, theta=(0.5,), weights=None, count: int = 0, run_id: str = RUN,
          status: str = "running") -> LearnerState:
    return LearnerState(run_id, "bracing", status, theta, (0.1,), kappa,
                        weights or dict(BRACING.default_weights), count)


def episode(index: int, theta: float = 0.4, status: str = "ok", damage: float = 0.0,
            body: float = 30.0, power: float = 0.5, attempt: int = 0, run_id: str = RUN) -> LearnerEpisode:
    eid = f"{run_id}.{index:05d}.{attempt}"
    request = EpisodeRequest(eid, "bracing", (theta,), 7)
    if status == "ok":
        terms = {"damage": damage, "body_acc_sq": body, "arm_power": power}
        result = EpisodeResult(eid, "bracing", "ok", terms, BRACING.total_cost(terms),
                               failures={"hardware_damage": damage > 0})
        cost = BRACING.total_cost(terms)
    else:
        result = EpisodeResult(eid, "bracing", status, {"body_acc_sq": 1.0}, None, detail="lost PDO")
        cost = None
    return LearnerEpisode(run_id, index, (0.5,), (theta - 0.5,), request, result, cost, 1.7e9 + index)


def _seqs(events):  # noqa: ANN001
    return [data["seq"] for _, data in events]


def test_episodes_become_points_with_increasing_seq_and_faults():
    model = DashboardModel("ubot1")
    events = model.add_episode(episode(0)) + model.add_episode(episode(1, status="fault_pdo_timeout"))
    events += model.add_episode(episode(1, damage=1.0, attempt=1))
    kinds = [k for k, _ in events]
    assert kinds == ["curve", "episode", "episode", "fault", "episode"]
    assert _seqs(events) == sorted(set(_seqs(events)))
    points = [d["point"] for k, d in events if k == "episode"]
    assert [p["status"] for p in points] == ["ok", "fault_pdo_timeout", "ok"]
    assert points[1]["cost"] is None and points[2]["damage"] and not points[0]["damage"]
    assert "fault_pdo_timeout" in model.last_fault and "lost PDO" in model.last_fault
    assert model.observations() == [((0.4,), points[0]["cost"]), ((0.4,), points[2]["cost"])]


def test_kappa_changes_are_marked_where_they_apply():
    model = DashboardModel("ubot1")
    assert [k for k, _ in model.set_state(state(kappa=2.0))] == ["curve", "state"]
    assert model.set_state(state(kappa=2.0)) == []  # nothing changed: no event
    model.add_episode(episode(0))
    (kind, data), = model.set_state(state(kappa=0.5, count=3))
    assert kind == "state"
    assert data["kappa_marks"] == [[0, 2.0], [3, 0.5]]
    assert data["means"][-1] == [3, [0.5]]


def test_weights_change_recosts_every_point():
    model = DashboardModel("ubot1")
    model.set_state(state())
    model.add_episode(episode(0, body=30.0, power=0.5))
    model.add_episode(episode(1, status="fault_emcy"))
    heavy = {"damage": 10.0, "body_acc_sq": 1.0, "arm_power": 20.0}
    events = model.set_state(state(weights=heavy))
    (curve,) = [d for k, d in events if k == "curve"]
    assert curve["points"][0]["cost"] == pytest.approx(30.0 + 20 * 0.5)
    assert curve["points"][1]["cost"] is None


def test_a_new_run_starts_a_new_curve():
    model = DashboardModel("ubot1")
    model.set_state(state())
    model.add_episode(episode(0))
    events = model.add_episode(episode(0, run_id="run-2"))
    assert events[0][0] == "curve" and events[0][1]["points"] == []
    assert [p.episode_id for p in model.points] == ["run-2.00000.0"]


@settings(max_examples=80, deadline=None)
@given(st.lists(st.sampled_from(["ok", "fault_heartbeat"]), min_size=1, max_size=10), st.data())
def test_history_and_live_episodes_make_one_curve_in_recording_order(statuses, data):
    """The dashboard subscribes when ``subscribed`` episodes are recorded, the learner reads the
    history when ``recorded`` are, and ``arrived`` live ones reached the dashboard before the
    history did: every episode is drawn once, in recording order, whatever the interleaving."""
    recorded_order = [episode(i, 0.1 * (i % 10), status) for i, status in enumerate(statuses)]
    n = len(recorded_order)
    subscribed = data.draw(st.integers(0, n), label="subscribed")
    recorded = data.draw(st.integers(subscribed, n), label="recorded")
    arrived = data.draw(st.integers(subscribed, n), label="arrived")
    model = DashboardModel("ubot1")
    model.set_state(state())
    for e in recorded_order[subscribed:arrived]:
        model.add_episode(e)
    events = model.load_history(RUN, recorded_order[:recorded])
    for e in recorded_order[arrived:]:
        events += model.add_episode(e)
    ids = [e.result.episode_id for e in recorded_order]
    assert [p.episode_id for p in model.points] == ids
    assert [p.seq for p in model.points] == list(range(n))
    assert sorted(model.means) == sorted({e.index for e in recorded_order})
    assert not [d for k, d in events if k == "episode" and d["point"]["episode_id"] in ids[:max(recorded, arrived)]]
    failed = [e for e in recorded_order if not e.result.ok]
    assert (failed[-1].result.episode_id in model.last_fault) if failed else model.last_fault == ""


def test_history_of_another_run_starts_a_new_curve():
    model = DashboardModel("ubot1")
    model.add_episode(episode(0))
    events = model.load_history("run-2", [episode(0, run_id="run-2"), episode(1, run_id="run-2")])
    assert [k for k, _ in events][:2] == ["curve", "curve"]
    assert [p.episode_id for p in model.points] == ["run-2.00000.0", "run-2.00001.0"]
    assert model.load_history("run-2", [episode(0, run_id="run-2")]) == []  # nothing new


def test_learner_unreachable_is_shown_once_and_cleared_by_a_state():
    model = DashboardModel("ubot1")
    model.set_state(state())
    (kind, data), = model.learner_unreachable("no answer")
    assert data["learner_note"] == "no answer"
    assert model.learner_unreachable("no answer") == []
    (kind, data), = model.set_state(state())
    assert kind == "state" and data["learner_note"] == ""


@settings(max_examples=60, deadline=None)
@given(task=st.sampled_from(sorted(TASKS)), n=st.integers(2, 30), kappa=st.floats(-10, 10),
       data=st.data())
def test_critic_slices_pass_through_theta_and_split_the_reply(task, n, kappa, data):
    spec = get_task(task)
    theta = _theta(spec, data.draw(st.lists(st.floats(0, 1), min_size=spec.dim, max_size=spec.dim)))
    query = critic_query(spec, theta, n)
    assert len(query.thetas) == spec.dim * n
    values = data.draw(st.lists(st.tuples(st.floats(-1e3, 1e3), st.floats(0, 1e3)),
                                min_size=len(query.thetas), max_size=len(query.thetas)))
    reply = CriticReply(task, kappa, tuple(CriticPoint(p, j, r, j + kappa * r)
                                           for p, (j, r) in zip(query.points_for(task), values)))
    obs = [(theta, 1.0)]
    view = critic_view(spec, theta, 4, reply, obs)
    assert len(view.slices) == spec.dim
    for i, s in enumerate(view.slices):
        assert s.x[0] == spec.lower[i] and s.x[-1] == pytest.approx(spec.upper[i])
        assert list(s.x) == sorted(s.x) and len(s.x) == n
        for k in range(n):
            point = reply.points[i * n + k]
            assert all(point.theta[j] == theta[j] for j in range(spec.dim) if j != i)
            assert (s.J[k], s.r[k], s.F[k]) == (point.J, point.r, point.F)
        assert s.at == theta[i] and s.obs_x == (theta[i],) and s.obs_y == (1.0,)


def test_critic_view_refuses_a_reply_of_the_wrong_size():
    reply = CriticReply("lifting", 0.0, (CriticPoint(get_task("lifting").lower, 1.0, 0.0, 1.0),) * 15)
    with pytest.raises(ValueError):
        critic_view(get_task("lifting"), get_task("lifting").lower, 0, reply, [])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1), st.sampled_from(["ok", "fault_heartbeat"]),
                          st.floats(0, 1e4), st.sampled_from([0.0, 1.0])), max_size=12),
       st.lists(st.floats(-10, 10), min_size=1, max_size=4))
def test_snapshot_is_strict_json_and_holds_everything_seen(episodes, kappas):
    model = DashboardModel("ubot1", read_only=True)
    for k, kappa in enumerate(kappas):
        model.set_state(state(kappa=kappa, count=k))
    for i, (theta, status, body, damage) in enumerate(episodes):
        model.add_episode(episode(i, theta, status, damage, body))
    snap = json.loads(json.dumps(model.snapshot(), allow_nan=False))
    assert snap["seq"] == model.seq and snap["read_only"] is True
    assert [p["episode_id"] for p in snap["points"]] == [p.episode_id for p in model.points]
    assert len(snap["points"]) == len(episodes)
    ok_costs = [p["cost"] for p in snap["points"] if p["status"] == "ok"]
    assert all(c is not None and math.isfinite(c) for c in ok_costs)
    changes = sum(1 for a, b in zip(kappas, kappas[1:]) if a != b)
    assert len(snap["kappa_marks"]) == 1 + changes


def test_the_agents_phase_is_shown_and_only_changes_make_events():
    model = DashboardModel("ubot1")
    assert model.set_agent_alive(True)[0][1]["alive"] is True
    ((kind, data),) = model.set_agent_state("waiting_for_go", "no test bench: reset the robot, then ersac-hil go")
    assert kind == "agent" and data["phase"] == "waiting_for_go" and data["alive"] is True
    assert model.set_agent_state("waiting_for_go", "no test bench: reset the robot, then ersac-hil go") == []
    snap = model.snapshot()
    assert snap["agent_phase"] == "waiting_for_go" and "ersac-hil go" in snap["agent_detail"]
    assert model.set_agent_state("stopped", "e-stop engaged: test")[0][1]["phase"] == "stopped"
    model.set_agent_alive(False)
    assert model.snapshot()["agent_phase"] is None  # an absent agent has no phase
    json.dumps(model.snapshot())
