"""Batched ask/tell (a fleet evaluating k perturbations per update): k = 1 is ask/tell bit for
bit, the update is the average of the rows' eq. 10 terms, state round-trips, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.learner import (
    ERSAC,
    InvalidInputError,
    NoPendingAskError,
    PendingAskError,
    PendingMismatchError,
)


def make(seed: int = 0, d: int = 1, kappa: float = 2.0, **kw) -> ERSAC:
    args = dict(theta0=[0.3] * d, sigma=0.08, eta=0.2, kappa=kappa, epsilon=0.3,
                bounds=[[0.0, 1.0]] * d, seed=seed)
    args.update(kw)
    return ERSAC(**args)


def cost(x: np.ndarray, noise: np.random.Generator) -> float:
    """A noisy bowl whose noise grows with x[0] (shape of x: (d,))."""
    return float(3.0 * np.sum((x - 0.6) ** 2) + (0.1 + x[0]) * noise.standard_normal())


def state(learner: ERSAC) -> str:
    return json.dumps(learner.get_state(), sort_keys=True)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), d=st.sampled_from([1, 2]), kappa=st.sampled_from([0.0, 2.0]),
       interleave=st.sampled_from([0, 3]))
def test_a_batch_of_one_is_ask_tell_bit_for_bit(seed, d, kappa, interleave):
    one, batch = make(seed, d, kappa, interleave_every=interleave), make(seed, d, kappa, interleave_every=interleave)
    noise_a, noise_b = np.random.default_rng(seed + 1), np.random.default_rng(seed + 1)
    for _ in range(14):
        x = one.ask()
        u = one.tell(x, cost(x, noise_a))
        X = batch.ask_batch(1)
        v = batch.tell_batch(X, [cost(X[0], noise_b)])
        np.testing.assert_array_equal(X[0], x)
        assert (v.theta_after.tobytes(), v.J_tilde, v.r_tilde, v.r_tilde_perturbed, v.td_error, v.cost,
                v.step_size, v.warmup, v.skipped) == (u.theta_after.tobytes(), u.J_tilde, u.r_tilde,
                                                      u.r_tilde_perturbed, u.td_error, u.cost, u.step_size,
                                                      u.warmup, u.skipped)
        assert v.executed.shape == (1, d) and v.z.shape == (1, d)
    assert state(one) == state(batch)


def test_rows_come_from_the_same_stream_as_successive_asks():
    a, b = make(5, d=2), make(5, d=2)
    X = a.ask_batch(3)
    rows = []
    for _ in range(3):
        rows.append(b.ask())
        b.discard()
    np.testing.assert_array_equal(X, np.array(rows))
    np.testing.assert_array_equal(a.ask_batch(3), X)  # idempotent until told


@pytest.mark.parametrize("k", [2, 4])
def test_the_update_averages_the_rows_eq10_terms(k):
    """kappa = 0, no move guard, no clipping: theta' = theta - alpha mean_i((J^_i - J~) z_i)."""
    learner = make(3, d=2, kappa=0.0, max_step=None, bounds=[[-10.0, 10.0]] * 2, theta0=[0.3, 0.3])
    noise = np.random.default_rng(4)
    steps = 0
    for _ in range(8):
        X = learner.ask_batch(k)
        costs = [cost(x, noise) for x in X]
        u = learner.tell_batch(X, costs)
        if u.warmup:  # fewer observations than the critic's 10 neighbours
            assert learner.n_observations < 10 and np.array_equal(u.theta_after, u.theta_before)
            continue
        steps += 1
        Z = X - u.theta_before
        expected = u.theta_before - u.step_size * np.mean((np.array(costs) - u.J_tilde)[:, None] * Z, axis=0)
        np.testing.assert_allclose(u.theta_after, expected, rtol=0, atol=1e-12)
        assert u.cost == pytest.approx(np.mean(costs)) and u.z.shape == (k, 2)
    assert steps >= 3 and learner.n_observations == 8 * k and learner.n_updates == 8


def test_a_refused_row_is_redrawn_alone():
    learner = make(8, d=2)
    X = learner.ask_batch(3)
    new = learner.reask(1)
    Y = learner.pending
    np.testing.assert_array_equal(Y[[0, 2]], X[[0, 2]])
    np.testing.assert_array_equal(Y[1], new)
    assert not np.array_equal(new, X[1])


def test_a_pending_batch_survives_save_and_restore():
    ref = make(2)
    noise = np.random.default_rng(0)
    for _ in range(4):
        X = ref.ask_batch(3)
        ref.tell_batch(X, [cost(x, noise) for x in X])
    X = ref.ask_batch(3)
    saved = json.loads(json.dumps(ref.get_state()))
    resumed = ERSAC.from_state(saved)
    for x, c in zip(ref.observations.points, ref.observations.costs):
        resumed.observe(x, float(c))
    np.testing.assert_array_equal(resumed.pending, X)
    costs = [cost(x, noise) for x in X]
    assert ref.tell_batch(X, costs).theta_after.tobytes() == resumed.tell_batch(X, costs).theta_after.tobytes()
    assert state(ref) == state(resumed)


def test_mixing_single_and_batched_asks_or_bad_batches_change_nothing():
    learner = make(1, d=2)
    with pytest.raises(NoPendingAskError):
        learner.tell_batch(np.zeros((2, 2)), [1.0, 1.0])
    with pytest.raises(InvalidInputError):
        learner.ask_batch(0)
    X = learner.ask_batch(2)
    before = state(learner)
    with pytest.raises(PendingAskError):
        learner.ask()
    with pytest.raises(PendingAskError):
        learner.ask_batch(3)
    with pytest.raises(NoPendingAskError):
        learner.tell(X[0], 1.0)
    with pytest.raises(InvalidInputError):
        learner.tell_batch(X, [1.0])  # one cost short
    with pytest.raises(InvalidInputError):
        learner.tell_batch(X[:1], [1.0])
    with pytest.raises(PendingMismatchError):
        learner.tell_batch(X[::-1], [1.0, 2.0])
    with pytest.raises(InvalidInputError):
        learner.tell_batch(X, [1.0, float("nan")])  # validated before anything is recorded
    with pytest.raises(InvalidInputError):
        learner.reask(2)
    assert state(learner) == before and learner.n_observations == 0
    learner.tell_batch(X, [1.0, 2.0])
    assert learner.n_observations == 2 and learner.pending is None
    learner.ask()
    with pytest.raises(PendingAskError):
        learner.ask_batch(1)
