"""The simulator's landscape as the critic's prior mean (residual model, critic/prior.py):
exactness of the residual decomposition, gradients, resume, re-weighting, bad input, and
what the prior buys (and costs) on a cost the simulator gets right or wrong."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.critic import CriticConfig, CriticInputError, CriticPrior, LocalCritic
from ersac_hil.learner import ERSAC, CostWeights
from ersac_hil.learner.costs import Observations

GRID = np.linspace(0.0, 1.0, 11)


def sim_prior(shift: float = 0.0) -> CriticPrior:
    """A bracing-shaped landscape: the mean falls with theta, the spread rises past 0.35 + shift."""
    m = 200.0 - 60.0 * GRID
    s = 5.0 + 40.0 / (1.0 + np.exp(-(GRID - 0.45 - shift) / 0.05))
    return CriticPrior(tuple(GRID), tuple(m), tuple(s))


def observations(X: np.ndarray, y: np.ndarray) -> Observations:
    obs = Observations(1)
    for x, c in zip(X, y):
        obs.add(np.atleast_1d(x), float(c))
    return obs


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), n=st.integers(10, 30), centre=st.floats(0.25, 0.75), follows=st.booleans())
def test_the_residual_model_is_the_prior_plus_a_fit_of_the_residuals_where_that_explains_more(
        seed: int, n: int, centre: float, follows: bool) -> None:
    """The prior's mean is used exactly when the VHGP of the residuals has the higher bound
    (evidence) than the VHGP of the costs, and then J~ is the prior plus that fit."""
    rng = np.random.default_rng(seed)
    prior = sim_prior()
    X = np.clip(centre + 0.08 * rng.standard_normal((n, 1)), 0, 1)
    m = prior.mean_at(X)[0]
    y = (m if follows else 150.0 + 40.0 * np.sin(20.0 * X[:, 0])) + 5.0 * rng.standard_normal(n)
    with_prior = LocalCritic(observations(X, y), CriticConfig(epsilon=0.2, prior=prior, noise_model="vhgp"))
    residual = LocalCritic(observations(X, y - m), CriticConfig(epsilon=0.2, noise_model="vhgp"))
    plain = LocalCritic(observations(X, y), CriticConfig(epsilon=0.2, noise_model="vhgp"))
    ids = np.arange(n)
    a, b, c = with_prior.fit_ids(ids), residual.fit_ids(ids), plain.fit_ids(ids)
    chose_prior = b.model.bound() > c.model.bound()
    assert (a.prior is prior) == chose_prior
    Xs = np.linspace(0, 1, 7)[:, None]
    pa = a.predict(Xs)
    expected = b.predict(Xs).f_mean + prior.mean_at(Xs)[0] if chose_prior else c.predict(Xs).f_mean
    np.testing.assert_allclose(pa.f_mean, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(a.costs, y)  # what it was fitted to, not the residuals


def test_costs_that_follow_the_simulated_mean_are_mostly_explained_by_it() -> None:
    """The residual model has the higher bound for costs that are the simulated mean plus
    noise - mostly, not always: over a narrow neighbourhood (the mean changes by ~17 there) a
    plain VHGP of the costs can fit the trend as well, and the evidence then keeps it (measured
    at 25 points: 37 of seeds 0-39; the hypothesis test above once drew seed 5294, a 2.6 lower
    bound). The prior then is not used for that fit, as with no prior."""
    prior, n = sim_prior(), 25
    chosen = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        X = np.clip(0.5 + 0.08 * rng.standard_normal((n, 1)), 0, 1)
        y = prior.mean_at(X)[0] + 5.0 * rng.standard_normal(n)
        fit = LocalCritic(observations(X, y), CriticConfig(epsilon=0.2, prior=prior, noise_model="vhgp")).fit_ids(
            np.arange(n))
        chosen += fit.prior is prior
    assert chosen >= 34, chosen


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), x=st.floats(0.3, 0.7), kappa=st.floats(0.0, 3.0))
def test_gradients_of_the_prior_critic_match_finite_differences(seed: int, x: float, kappa: float) -> None:
    rng = np.random.default_rng(seed)
    prior = sim_prior()
    X = np.clip(0.5 + 0.1 * rng.standard_normal((25, 1)), 0, 1)
    y = prior.mean_at(X)[0] + 10.0 + np.exp(0.5 * prior.log_var_at(X)[0]) * rng.standard_normal(25)
    fit = LocalCritic(observations(X, y), CriticConfig(epsilon=0.3, prior=prior)).fit_ids(np.arange(25))
    h = 1e-6
    e = fit.estimate(np.array([x]), kappa)
    lo, hi = fit.estimate(np.array([x - h]), kappa), fit.estimate(np.array([x + h]), kappa)
    assert e.grad_J[0] == pytest.approx((hi.J - lo.J) / (2 * h), rel=1e-3, abs=1e-3)
    assert e.grad_F[0] == pytest.approx((hi.F - lo.F) / (2 * h), rel=1e-3, abs=1e-3)  # finite differences


def test_the_noise_follows_the_simulated_shape_where_the_data_cannot_tell() -> None:
    """30 points in the quiet part below the rise: without a prior r~ is flat beyond them
    (and its level the data's); with the prior r~ rises where the simulator's spread rises
    (within e^0.25 of the truth there, nearer than without)."""
    rng = np.random.default_rng(3)
    prior = sim_prior()
    X = np.clip(0.3 + 0.05 * rng.standard_normal((30, 1)), 0, 1)
    sd = np.exp(0.5 * prior.log_var_at(X)[0])
    y = prior.mean_at(X)[0] + sd * rng.standard_normal(30)
    ids = np.arange(30)
    fit_p = LocalCritic(observations(X, y), CriticConfig(epsilon=0.2, prior=prior)).fit_ids(ids)
    fit_0 = LocalCritic(observations(X, y), CriticConfig(epsilon=0.2)).fit_ids(ids)
    at = np.array([[0.55]])
    truth = float(np.exp(0.5 * prior.log_var_at(at)[0][0]))
    r_p, r_0 = float(fit_p.predict(at).noise_std[0]), float(fit_0.predict(at).noise_std[0])
    assert fit_p.noise.prior is prior  # the simulated shape explains these residuals better
    assert abs(math.log(r_p / truth)) < min(0.25, abs(math.log(r_0 / truth)))


def test_a_prior_survives_resume_bit_identically_and_goes_with_a_reweighting() -> None:
    prior = sim_prior()

    def make() -> ERSAC:
        return ERSAC([0.3], 0.05, 0.7, 2.0, 0.2, [[0.0, 1.0]], seed=5, interleave_every=1,
                     critic=CriticConfig(epsilon=0.2, prior=prior))

    noise = np.random.default_rng(1).standard_normal(30)
    cost = lambda x, i: float(prior.mean_at([[x[0]]])[0][0] + 8.0 * noise[i])  # noqa: E731
    ref, cut = make(), make()
    for i in range(14):
        x = cut.ask()
        cut.tell(x, {"cost": cost(x, i)})
    state = json.loads(json.dumps(cut.get_state()))
    assert state["critic"]["prior"] == prior.to_dict()
    resumed = ERSAC.from_state(state)
    for x, row in zip(cut.observations.points, cut.observations.terms):
        resumed.observe(x, {"cost": float(row[0])})
    assert resumed.critic_prior == prior
    for i in range(30):
        x = ref.ask()
        if i < 14:
            ref.tell(x, {"cost": cost(x, i)})
            continue
        xb = resumed.ask()
        np.testing.assert_array_equal(x, xb)
        assert ref.tell(x, {"cost": cost(x, i)}).to_dict() == resumed.tell(xb, {"cost": cost(xb, i)}).to_dict()
    resumed.reweight(CostWeights({"cost": 1.0}))  # the same weights: kept
    assert resumed.critic_prior == prior
    resumed.reweight(CostWeights({"cost": 2.0}))  # the simulator's costs no longer apply
    assert resumed.critic_prior is None
    assert "prior" not in resumed.get_state()["critic"]


@pytest.mark.parametrize("theta, mean, std, says", [
    ((0.0,), (1.0,), (1.0,), "length >= 2"),
    ((0.0, 1.0), (1.0,), (1.0, 1.0), "same length"),
    ((0.0, 0.0), (1.0, 2.0), (1.0, 1.0), "strictly increasing"),
    ((0.0, 1.0), (1.0, math.nan), (1.0, 1.0), "finite"),
    ((0.0, 1.0), (1.0, 2.0), (1.0, -1.0), "std >= 0"),
])
def test_a_bad_landscape_is_refused_naming_why(theta, mean, std, says) -> None:  # noqa: ANN001
    with pytest.raises(CriticInputError, match=says):
        CriticPrior(theta, mean, std)


def test_a_one_dimensional_prior_refuses_other_dimensions() -> None:
    with pytest.raises(CriticInputError, match="1-D landscape"):
        sim_prior().mean_at(np.zeros((3, 2)))
    with pytest.raises(CriticInputError, match="CriticPrior"):
        CriticConfig(epsilon=0.2, prior={"theta": [0, 1]})  # type: ignore[arg-type]


@pytest.mark.parametrize("shift", [0.0, 0.2])
def test_a_learner_with_a_prior_from_a_wrong_simulator_recovers(shift: float) -> None:
    """kappa 2 on a robot whose cost is the landscape's mean with sim_prior(shift)'s spread:
    the risk-averse optimum is 0.29 + shift (the spread rises past it), the simulator says
    0.29 (shift 0). The run starts at the simulated optimum with the simulator's critic
    prior, as a run with ``--prior`` does; with a simulator wrong by 0.2 (the robot's noise
    rises 0.2 later) the final selection still ends within 0.1 of the robot's optimum."""
    prior, robot = sim_prior(), sim_prior(shift)
    L = ERSAC([0.29], 0.05, 0.7, 2.0, 0.2, [[0.0, 1.0]], seed=4, interleave_every=1,
              critic=CriticConfig(epsilon=0.2, prior=prior))
    rng = np.random.default_rng(11)
    for _ in range(45):
        x = L.ask()
        L.tell(x, float(robot.mean_at([x])[0][0] + math.exp(0.5 * robot.log_var_at([x])[0][0]) * rng.standard_normal()))
    assert abs(float(L.select(2.0, pessimism=2.0).theta[0]) - (0.29 + shift)) <= 0.1


def _run(L: ERSAC, n: int, seed: int = 2, prior: CriticPrior | None = None) -> list:
    rng = np.random.default_rng(seed)
    truth = prior or sim_prior()
    out = []
    for _ in range(n):
        x = L.ask()
        out.append(L.tell(x, float(truth.mean_at([x])[0][0] + 6.0 * rng.standard_normal())))
    return out


def test_without_a_critic_prior_the_prior_rule_changes_nothing() -> None:
    """The prior rule (ERSAC prior_greedy) acts only while the critic has a prior: a learner
    without one takes the same steps, and saves the same state, whatever its prior rule."""
    from ersac_hil.learner.ersac import PRIOR_GREEDY
    make = lambda rule: ERSAC([0.3], 0.05, 0.7, 2.0, 0.2, [[0.0, 1.0]], seed=7, interleave_every=1,  # noqa: E731
                              prior_greedy=rule)
    a, b = make(None), make(PRIOR_GREEDY)
    assert [u.to_dict() for u in _run(a, 25)] == [u.to_dict() for u in _run(b, 25)]
    assert a.get_state() == b.get_state() and "prior_greedy" not in a.get_state()


def test_while_the_prior_is_kept_theta_moves_only_by_model_steps_and_after_its_rejection_by_gradient_steps(
        ) -> None:
    """With a critic prior the policy mean moves only to the argmin of F~ within 2 sigma, and
    only where F~ + sd(F~) is lower than at theta (no single-episode gradient step); once the
    prior is taken away (rejected) the preset's gradient steps are back (here the guarded
    rule: no interleaved search)."""
    L = ERSAC([0.35], 0.05, 0.7, 2.0, 0.2, [[0.0, 1.0]], seed=3,
              critic=CriticConfig(epsilon=0.2, prior=sim_prior()))
    kept = [u for u in _run(L, 30) if not u.warmup]
    assert all(u.offline or np.array_equal(u.theta_after, u.theta_before) for u in kept)
    assert all(abs(u.theta_after[0] - u.theta_before[0]) <= 2 * 0.05 + 1e-9 for u in kept)
    L.set_critic_prior(None)
    after = _run(L, 8, seed=5)
    assert not any(u.offline for u in after)
    assert sum(not np.array_equal(u.theta_after, u.theta_before) for u in after) >= 6


def test_a_state_saved_before_the_prior_rule_resumes_with_the_steps_it_was_made_with() -> None:
    L = ERSAC([0.3], 0.05, 0.7, 2.0, 0.2, [[0.0, 1.0]], seed=5, interleave_every=1,
              critic=CriticConfig(epsilon=0.2, prior=sim_prior()))
    _run(L, 12)
    state = json.loads(json.dumps(L.get_state()))
    assert state["prior_greedy"]["around"] == "before"
    assert ERSAC.from_state(state)._prior_greedy == L._prior_greedy
    legacy = {k: v for k, v in state.items() if k != "prior_greedy"}
    assert ERSAC.from_state(legacy)._prior_greedy is None
