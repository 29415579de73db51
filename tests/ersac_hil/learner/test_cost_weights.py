"""CostWeights validation and exact re-weighting of stored observations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.learner import (
    ERSAC,
    CostWeights,
    InvalidCostError,
    InvalidInputError,
    MissingTermError,
    Observations,
    UnknownTermError,
)
from protocol.zenoh import TASKS

NAMES = ("energy", "impact", "translation")
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


def test_weights_are_a_frozen_sorted_mapping() -> None:
    w = CostWeights({"translation": 2.0, "energy": 0.5})
    assert list(w) == ["energy", "translation"] and len(w) == 2 and w["energy"] == 0.5
    assert w == CostWeights({"energy": 0.5, "translation": 2.0}) and hash(w) == hash(CostWeights(dict(w)))
    with pytest.raises(TypeError):
        w["energy"] = 1.0  # type: ignore[index]
    assert CostWeights(w.to_dict()) == w


@pytest.mark.parametrize(
    "bad",
    [{}, {"": 1.0}, {1: 1.0}, {"a": float("nan")}, {"a": float("inf")}, {"a": "1"}, {"a": None}, {"a": True}, [("a", 1.0)]],
)
def test_invalid_weights(bad) -> None:
    with pytest.raises(InvalidInputError):
        CostWeights(bad)


def test_terms_must_match_the_weights() -> None:
    w = CostWeights({"impact": 1.0, "energy": 5.0})
    assert w.combine({"impact": 2.0, "energy": 0.1}) == 0.1 * 5.0 + 2.0
    with pytest.raises(MissingTermError):
        w.combine({"impact": 2.0})
    with pytest.raises(UnknownTermError):
        w.combine({"impact": 2.0, "energy": 0.1, "damage": 10.0})
    with pytest.raises(InvalidCostError):
        w.combine({"impact": float("nan"), "energy": 0.1})
    with pytest.raises(MissingTermError):
        w.combine(3.0)
    assert CostWeights({"cost": 2.0}).combine(3.0) == 6.0


@settings(max_examples=40, deadline=None)
@given(
    terms=st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=30),
    w1=st.tuples(finite, finite, finite),
    w2=st.tuples(finite, finite, finite),
)
def test_reweighting_recomputes_every_cost_exactly(terms, w1, w2) -> None:
    W1, W2 = CostWeights(dict(zip(NAMES, w1))), CostWeights(dict(zip(NAMES, w2)))
    observations = Observations(1, W1)
    for i, t in enumerate(terms):
        observations.add([i * 0.01], dict(zip(NAMES, t)))
    original = observations.costs.copy()
    # every cost equals the weighted sum computed on its own, bit for bit
    assert original.tolist() == [W1.combine(dict(zip(NAMES, t))) for t in terms]
    observations.reweight(W2)
    assert observations.costs.tolist() == [W2.combine(dict(zip(NAMES, t))) for t in terms]
    observations.reweight(W1)
    assert observations.costs.tolist() == original.tolist()  # exact round trip


def test_reweight_rejects_other_term_sets_and_changes_nothing() -> None:
    observations = Observations(1, CostWeights({"impact": 1.0, "energy": 1.0}))
    observations.add([0.0], {"impact": 1.0, "energy": 2.0})
    before = observations.costs.copy()
    with pytest.raises(MissingTermError):
        observations.reweight(CostWeights({"impact": 1.0}))
    with pytest.raises(UnknownTermError):
        observations.reweight(CostWeights({"impact": 1.0, "energy": 1.0, "damage": 3.0}))
    assert observations.costs.tolist() == before.tolist() and observations.weights == CostWeights({"impact": 1.0, "energy": 1.0})


def test_learner_reweight_changes_the_critic_and_is_exact() -> None:
    """Energy-averse vs translation-averse contexts: the same episodes, other costs."""
    rng = np.random.default_rng(0)
    base = CostWeights({"energy": 1.0, "translation": 1.0})
    L = ERSAC([0.5], 0.15, 0.1, 0.0, 0.4, [[0.0, 1.0]], seed=1, weights=base)
    for _ in range(25):
        x = L.ask()
        L.tell(x, {"energy": 2.0 * x[0] + 0.1 * rng.standard_normal(), "translation": 2.0 * (1 - x[0]) + 0.1 * rng.standard_normal()})
    theta = np.array([0.5])
    before = L.observations.costs.copy()
    slope_base = L.critic_estimate(theta).grad_J[0]
    L.reweight(CostWeights({"energy": 10.0, "translation": 1.0}))  # energy-averse
    slope_energy = L.critic_estimate(theta).grad_J[0]
    T = L.observations.terms
    assert L.observations.costs.tolist() == (0.0 + 10.0 * T[:, 0] + 1.0 * T[:, 1]).tolist()
    L.reweight(CostWeights({"energy": 1.0, "translation": 10.0}))  # translation-averse
    slope_translation = L.critic_estimate(theta).grad_J[0]
    assert slope_energy > 5.0 and slope_translation < -5.0 and abs(slope_base) < 3.0
    L.reweight(base)
    assert L.observations.costs.tolist() == before.tolist()
    assert not math.isnan(slope_base)


@settings(max_examples=60, deadline=None)
@given(task=st.sampled_from(sorted(TASKS)), data=st.data())
def test_the_learners_cost_is_the_agents_total_cost_bit_for_bit(task, data) -> None:
    """The cost the learner fits and the total the agent reports (and the store's, the
    dashboard's, reproduce's) are one sum (the contract's ``weighted_total``), to the last bit;
    lifting's six terms told the two apart when they were summed in two ways."""
    spec = TASKS[task]
    terms = data.draw(st.fixed_dictionaries({n: st.floats(0.0, 1e4) for n in spec.term_names}))
    weights = data.draw(st.fixed_dictionaries({n: st.floats(0.0, 100.0) for n in spec.term_names}))
    assert CostWeights(spec.default_weights).combine(terms) == spec.total_cost(terms)
    assert CostWeights(weights).combine(terms) == spec.total_cost(terms, weights)
    rows = np.array([[terms[n] for n in sorted(spec.term_names)]] * 3)
    assert CostWeights(weights).combine_rows(rows).tolist() == [spec.total_cost(terms, weights)] * 3
