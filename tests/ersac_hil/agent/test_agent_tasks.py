"""The task registry: one task object per contract task, looked up by name, refusing others."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.agent.errors import LimitViolation
from ersac_hil.agent.tasks import BracingTask, LiftingTask, UnknownTask, default_tasks, lookup
from protocol.zenoh import TASKS, EpisodeRequest, InvalidField


def test_every_contract_task_is_served_by_default_and_nothing_else():
    tasks = default_tasks()
    assert set(tasks) == set(TASKS)
    assert all(task.name == name and task.spec is TASKS[name] for name, task in tasks.items())


@pytest.mark.parametrize("name", ["juggling", "", "Bracing"])
def test_unknown_names_are_refused_with_unknown_task(name):
    with pytest.raises(UnknownTask) as info:
        lookup(default_tasks(), name)
    assert info.value.code == "unknown_task" and "bracing" in str(info.value)


def test_a_subset_serves_only_its_tasks():
    tasks = {"bracing": BracingTask()}
    assert isinstance(lookup(tasks, "bracing"), BracingTask)
    with pytest.raises(UnknownTask):
        lookup(tasks, "lifting")


@given(theta=st.floats(0.0, 1.0))
def test_bracing_plan_is_the_policy_impedance(theta):
    task = BracingTask()
    setup = task.plan((theta,))
    assert setup.impedance == task.policy.impedance(theta) and setup.pose == task.policy.pose


@pytest.mark.parametrize("task, theta", [("bracing", (1.1,)), ("bracing", (-0.1,)), ("bracing", (0.5, 0.5)),
                                         ("bracing", (float("nan"),)), ("lifting", (1.2,) * 6),
                                         ("lifting", (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 2.5))])
def test_theta_outside_the_contract_is_refused_once_where_the_request_arrives(task, theta):
    """The one check of theta's shape and bounds: the contract's, when the request is made
    (or decoded); a task's plan only ever gets a checked theta."""
    with pytest.raises(InvalidField):
        EpisodeRequest("ep", task, theta, 0)


def test_lifting_plan_checks_the_spline_before_anything_moves():
    task = LiftingTask()
    setup = task.plan((1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2))
    assert setup.spline.duration == pytest.approx(3.6)
    with pytest.raises(LimitViolation):
        task.plan((3.0, 0.2, 0.0, 2.4, 0.2, 0.2, 0.2))
