"""Offline policy selection: trust region, known optima, no episodes."""

from __future__ import annotations

import numpy as np
import pytest

from ersac_hil.critic import CriticConfig, LocalCritic
from ersac_hil.learner import ERSAC, InsufficientDataError, InvalidInputError, SelectionConfig, select_policy


def J(t):
    return 3.0 - 2.4 * t + 1.5 * t * t


def r(t):
    return 0.1 + 1.2 * t * t


def learner_with_data(xs: np.ndarray, seed: int = 0) -> ERSAC:
    L = ERSAC([0.3], 0.1, 0.1, 2.0, 0.3, [[0.0, 1.0]], seed=seed)
    noise = np.random.default_rng(seed)
    for x in xs:
        L.observe([x], float(J(x) + r(x) * noise.standard_normal()))
    return L


def test_finds_the_risk_sensitive_optimum_inside_the_data() -> None:
    """kappa = 2: F = 3.2 - 2.4 t + 3.9 t^2, optimum 0.308; data cover [0, 1]."""
    L = learner_with_data(np.random.default_rng(1).uniform(0, 1, 150))
    n_before = L.n_observations
    s = L.select(2.0, radius=0.1)
    assert abs(s.theta[0] - 0.308) < 0.08, s
    assert s.F_tilde == pytest.approx(s.J_tilde + 2.0 * s.r_tilde)
    assert s.distance_to_data <= 0.1 + 1e-9 and s.kappa == 2.0
    # optimal under the model: no observed point has a lower F~
    fit = L.local_critic.fit_ids(np.arange(150), local=False)
    assert s.F_tilde <= fit.estimate_many(L.observations.points, 2.0)[2].min() + 1e-9
    # risk-neutral selection is stiffer (the noise there, 0.5-1.3, hides where exactly
    # J's flat optimum at 0.8 lies: J(0.5) - J(0.8) = 0.135)
    s0 = L.select(0.0, radius=0.1)
    assert s0.theta[0] > s.theta[0] + 0.1
    assert L.n_observations == n_before and L.pending is None  # no episodes


def test_finds_a_known_optimum_in_2d() -> None:
    """J = 1 + 2 |theta - (0.6, 0.4)|^2, r = 0.05 + 0.1 theta_1: with kappa = 1 the optimum
    is (0.6 - 0.1 / 4, 0.4) = (0.575, 0.4)."""
    rng = np.random.default_rng(4)
    L = ERSAC([0.5, 0.5], 0.1, 0.1, 1.0, 0.3, [[0.0, 1.0], [0.0, 1.0]], seed=0)
    for x in rng.uniform(0, 1, (150, 2)):
        mean = 1 + 2 * ((x - [0.6, 0.4]) ** 2).sum()
        L.observe(x, float(mean + (0.05 + 0.1 * x[0]) * rng.standard_normal()))
    s = L.select(1.0, radius=0.1)
    np.testing.assert_allclose(s.theta, [0.575, 0.4], atol=0.06)


@pytest.mark.parametrize("radius", [0.02, 0.08])
def test_stays_in_the_trust_region(radius: float) -> None:
    """Data only on [0, 0.5]; J falls towards 0.8, so kappa = 0 pushes against the region."""
    L = learner_with_data(np.random.default_rng(2).uniform(0.0, 0.5, 120))
    s = L.select(0.0, radius=radius)
    assert s.distance_to_data <= radius * (1 + 1e-6)
    edge = L.observations.points.max()
    assert edge + radius * (1 + 1e-6) >= s.theta[0] > edge - 0.05


def test_trust_region_in_2d() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 0.4, (100, 2))
    y = 1.0 + ((pts - 0.9) ** 2).sum(1) + 0.05 * rng.standard_normal(100)

    class Data:
        points, costs = pts, y

    critic = LocalCritic(Data(), CriticConfig(epsilon=0.3))
    cfg = SelectionConfig(radius=0.05)
    s = select_policy(critic, np.array([[0.0, 1.0], [0.0, 1.0]]), 0.0, anchor=np.array([0.2, 0.2]), config=cfg)
    d = np.linalg.norm(pts - s.theta, axis=1).min()
    assert d <= 0.05 * (1 + 1e-6) and s.distance_to_data == pytest.approx(d)
    assert s.theta.sum() > 0.75  # pushed towards the optimum (0.9, 0.9) as far as allowed


def test_selection_needs_data_and_valid_options() -> None:
    L = learner_with_data(np.array([0.1, 0.2]))
    with pytest.raises(InsufficientDataError):
        L.select(1.0)
    L = learner_with_data(np.linspace(0, 1, 20))
    with pytest.raises(InvalidInputError):
        L.select(1.0, radius=-1.0)
    with pytest.raises(InvalidInputError):
        L.select(1.0, bogus=3)


def _upper(fit, x, kappa, z):  # noqa: ANN001, ANN202
    e = fit.estimate(np.asarray(x, dtype=float), kappa)
    return e.F + z * np.sqrt(max(e.J_var, 0.0) + kappa**2 * e.r**2 * max(e.g_var, 0.0) / 4.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pessimistic_selection_stays_where_the_data_are(seed) -> None:
    """Dense data on [0.2, 0.4], four points at 0.5-0.55: the plain argmin may sit at the thin
    edge; with pessimism the result is the candidate of lowest F~ + z sd(F~) - never above
    the plain argmin's bound - and an observed point or that argmin."""
    rng = np.random.default_rng(seed)
    xs = np.concatenate([rng.uniform(0.2, 0.4, 40), rng.uniform(0.5, 0.55, 4)])
    L = learner_with_data(xs, seed)
    plain = L.select(2.0, radius=0.1)
    careful = L.select(2.0, radius=0.1, pessimism=2.0)
    fit = L.local_critic.fit_ids(np.arange(len(xs)), local=False)
    assert _upper(fit, careful.theta, 2.0, 2.0) <= _upper(fit, plain.theta, 2.0, 2.0) + 1e-9
    assert np.allclose(careful.theta, plain.theta) or np.min(np.abs(xs - careful.theta[0])) < 1e-12
    assert L.select(2.0, radius=0.1, pessimism=0.0).theta == pytest.approx(plain.theta)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_a_bad_pessimism_is_refused(bad) -> None:
    L = learner_with_data(np.linspace(0.2, 0.4, 12))
    with pytest.raises(InvalidInputError, match="pessimism"):
        L.select(2.0, pessimism=bad)
