"""Offline selection on costs with two modes (a task that succeeds or fails as a
deterministic function of theta): the low mode is told apart, the failure side avoided."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.learner import ERSAC
from ersac_hil.learner.selection import low_mode


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 300), st.integers(0, 2**32 - 1),
       st.sampled_from(["normal", "lognormal", "exponential", "uniform"]))
def test_one_mode_costs_are_not_split(n: int, seed: int, kind: str) -> None:
    rng = np.random.default_rng(seed)
    y = {"normal": lambda: 160 + 30 * rng.standard_normal(n),
         "lognormal": lambda: np.exp(1.5 + 0.5 * rng.standard_normal(n)),
         "exponential": lambda: rng.exponential(8.0, n),
         "uniform": lambda: rng.uniform(5, 10, n)}[kind]()
    assert low_mode(y) is None


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 40), st.integers(3, 40), st.floats(0.0, 1.0), st.floats(25.0, 100.0),
       st.integers(0, 2**32 - 1))
def test_two_separated_modes_are_split_exactly(n_low: int, n_high: int, spread: float, gap: float,
                                                 seed: int) -> None:
    """Low costs 6 +- spread, high ones gap higher (as failed lifts: ~40 against 5-9)."""
    rng = np.random.default_rng(seed)
    low = 6.0 + spread * rng.uniform(-1, 1, n_low)
    high = 6.0 + gap + spread * rng.uniform(-1, 1, n_high)
    y = np.concatenate([low, high])
    perm = rng.permutation(y.size)
    mask = low_mode(y[perm])
    if y.size < 20:  # too few observations to tell modes from a heavy tail
        assert mask is None
    else:
        assert mask is not None
        np.testing.assert_array_equal(mask, perm < n_low)


def test_too_few_in_a_mode_or_a_non_positive_cost_is_left_to_the_noise_model() -> None:
    low = np.linspace(6.0, 7.0, 20)
    assert low_mode(np.concatenate([low, [40.0, 41.0]])) is None  # two failures: fewer than 3
    assert low_mode(np.concatenate([low, [40.0, 41.0, 40.5]])) is not None
    assert low_mode(np.concatenate([low - 6.0, [40.0, 41.0, 40.5]])) is None  # a zero cost: no log


def cliff_cost(x: np.ndarray) -> float:
    """Success (x0 < 0.5): a bowl around (0.3, 0.6); failure: ~40, as a failed lift."""
    if x[0] >= 0.5:
        return 40.0 + 0.5 * x[1]
    return 6.0 + 8.0 * ((x[0] - 0.3) ** 2 + (x[1] - 0.6) ** 2)


def test_selection_on_two_modes_stays_on_the_success_side_and_improves() -> None:
    """30 deterministic observations, half failures, anchor near the cliff: the selection
    leaves the anchor towards the bowl's minimum, on the success side, at a lower true cost."""
    rng = np.random.default_rng(7)
    L = ERSAC([0.45, 0.3], 0.05, 0.5, 2.0, 0.2, [[0.0, 1.0], [0.0, 1.0]], seed=0)
    X = rng.uniform(0, 1, (30, 2))
    for x in X:
        L.observe(x, cliff_cost(x))
    failed = int(sum(x[0] >= 0.5 for x in X))
    s = L.select(2.0, radius=0.1)
    assert s.n_excluded == failed > 3
    assert s.theta[0] < 0.5 and s.distance_to_data <= 0.1 * (1 + 1e-6)
    assert cliff_cost(s.theta) < cliff_cost(L.theta) - 0.3
    # nearer to an observed success than to any observed failure
    ok, bad = X[X[:, 0] < 0.5], X[X[:, 0] >= 0.5]
    assert np.linalg.norm(ok - s.theta, axis=1).min() <= np.linalg.norm(bad - s.theta, axis=1).min() + 1e-9
