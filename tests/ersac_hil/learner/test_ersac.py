"""ERSAC ask/tell: the update equation, clipping, kappa, determinism, resume, invalid input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ersac_hil.critic import CriticConfig, VHGP, VHGPParams
from ersac_hil.critic.noise import fit_log_linear
from ersac_hil.learner import (
    ERSAC,
    CostWeights,
    InvalidCostError,
    InvalidInputError,
    InvalidKappaError,
    LearnerError,
    MissingTermError,
    NoPendingAskError,
    OutOfBoundsError,
    PendingMismatchError,
    StateError,
    UnknownTermError,
)

BOUNDS = [[0.0, 1.0]]


def J(t: float) -> float:
    return 3.0 - 2.4 * t + 1.5 * t * t


def r(t: float) -> float:
    return 0.1 + 1.2 * t * t


def make(seed: int = 0, kappa: float = 2.0, **kw) -> ERSAC:
    args = dict(theta0=[0.2], sigma=0.1, eta=0.1, kappa=kappa, epsilon=0.3, bounds=BOUNDS, seed=seed)
    args.update(kw)
    return ERSAC(**args)


def episodes(learner: ERSAC, n: int, noise_seed: int = 1):
    noise = np.random.default_rng(noise_seed)
    out = []
    for _ in range(n):
        x = learner.ask()
        out.append(learner.tell(x, J(x[0]) + r(x[0]) * noise.standard_normal()))
    return out


def snapshot(learner: ERSAC) -> str:
    return json.dumps(learner.get_state(), sort_keys=True) + repr(learner.observations.points.tolist())


# ----------------------------------------------------------------------------- the update
def test_update_matches_hand_computation() -> None:
    L = make(seed=3, kappa=1.5)
    ups = episodes(L, 25)
    u = ups[-1]
    assert not u.warmup
    # independent rebuild of the critic the update used: same observations, same VHGP
    fit = L._last_fit
    X, y = L.observations.points[fit.ids], L.observations.costs[fit.ids]
    model = VHGP.from_params(X, y, VHGPParams(fit.model.params.log_lambda, fit.model.params.kernel))
    Xq = np.vstack([u.theta_before, u.executed])
    p = model.predict(Xq)
    # r~ from the log-linear noise model on the VHGP's leave-one-out residuals (the default)
    noise = fit_log_linear(X, *model.loo(), 10.0 / (X.max(0) - X.min(0)))
    g_mean, g_var = noise.predict(Xq)
    J_t, r_t, r_p = p.f_mean[0], math.sqrt(math.exp(g_mean[0] + g_var[0] / 2)), math.sqrt(math.exp(g_mean[1] + g_var[1] / 2))
    assert u.J_tilde == pytest.approx(J_t, rel=1e-12)
    assert u.r_tilde == pytest.approx(r_t, rel=1e-12)
    assert u.r_tilde_perturbed == pytest.approx(r_p, rel=1e-12)
    delta = u.cost - J_t + 1.5 * (r_p - r_t)
    alpha = min(max(0.1 / r_t, 0.01), 0.5)
    assert u.td_error == pytest.approx(delta, rel=1e-12)
    assert u.step_size == pytest.approx(alpha, rel=1e-12)
    np.testing.assert_allclose(u.z, u.executed - u.theta_before)
    np.testing.assert_allclose(u.theta_after, np.clip(u.theta_before - alpha * delta * u.z, 0, 1), rtol=1e-12)
    np.testing.assert_array_equal(L.theta, u.theta_after)
    # the observation was stored before the critic was fitted
    assert L.n_observations == 25 and fit.ids[-1] == 24


def test_warmup_stores_without_updating() -> None:
    L = make(min_observations=6)
    ups = episodes(L, 6)
    for u in ups[:5]:
        assert u.warmup and u.step_size == 0.0 and u.J_tilde is None
        np.testing.assert_array_equal(u.theta_after, [0.2])
    assert not ups[5].warmup
    assert L.n_observations == 6 and L.n_updates == 6


@pytest.mark.parametrize("eta,expected", [(1e-6, 0.01), (1e3, 0.5)])
def test_step_size_is_clipped_to_lr_range(eta: float, expected: float) -> None:
    L = make(eta=eta)
    ups = [u for u in episodes(L, 14) if not u.warmup]
    assert ups and all(u.step_size == expected for u in ups)
    L2 = make(eta=0.1, lr_range=(0.2, 0.3))
    assert all(0.2 <= u.step_size <= 0.3 for u in episodes(L2, 14) if not u.warmup)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 1000), theta0=st.sampled_from([0.0, 0.02, 0.98, 1.0]))
def test_parameters_stay_in_bounds(seed: int, theta0: float) -> None:
    L = make(seed=seed, theta0=[theta0], sigma=0.4, eta=5.0)
    for u in episodes(L, 15, noise_seed=seed):
        assert np.all(u.executed >= 0) and np.all(u.executed <= 1)
        assert np.all(u.theta_after >= 0) and np.all(u.theta_after <= 1)


def test_clipping_is_reported() -> None:
    L = make(theta0=[1.0], sigma=0.3, eta=5.0, kappa=-1.0)
    ups = episodes(L, 20)
    assert any(u.clipped for u in ups)
    assert all(u.theta_after[0] <= 1.0 for u in ups)


def test_kappa_change_takes_effect_at_next_update() -> None:
    a, b = make(seed=5, kappa=0.0), make(seed=5, kappa=0.0)
    ua, ub = episodes(a, 15), episodes(b, 15)
    np.testing.assert_array_equal(a.theta, b.theta)
    xa, xb = a.ask(), b.ask()
    np.testing.assert_array_equal(xa, xb)
    b.kappa = 3.0  # between ask and tell: applies to this tell
    assert b.kappa == 3.0
    cost = J(xa[0])
    va, vb = a.tell(xa, cost), b.tell(xb, cost)
    assert va.kappa == 0.0 and vb.kappa == 3.0
    assert vb.td_error - va.td_error == pytest.approx(3.0 * (vb.r_tilde_perturbed - vb.r_tilde), rel=1e-9)
    assert not np.array_equal(a.theta, b.theta)
    assert [u.kappa for u in ub] == [0.0] * 15  # history untouched


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), "1.0", None, True])
def test_invalid_kappa_is_rejected(bad) -> None:
    L = make(kappa=0.5)
    before = snapshot(L)
    with pytest.raises(InvalidKappaError):
        L.kappa = bad
    assert L.kappa == 0.5 and snapshot(L) == before
    with pytest.raises(InvalidKappaError):
        make(kappa=bad)


def test_deterministic_given_seed() -> None:
    a = [(u.executed.tolist(), u.theta_after.tolist(), u.td_error) for u in episodes(make(seed=9), 25)]
    b = [(u.executed.tolist(), u.theta_after.tolist(), u.td_error) for u in episodes(make(seed=9), 25)]
    c = [(u.executed.tolist(), u.theta_after.tolist(), u.td_error) for u in episodes(make(seed=10), 25)]
    assert a == b
    assert a != c


def test_ask_is_idempotent_until_tell() -> None:
    L = make()
    x1, x2 = L.ask(), L.ask()
    np.testing.assert_array_equal(x1, x2)
    np.testing.assert_array_equal(L.pending, x1)
    L.tell(x1, 1.0)
    assert L.pending is None
    assert not np.array_equal(L.ask(), x1)


# ----------------------------------------------------------------------------- resume
def _resume(L: ERSAC) -> ERSAC:
    state = json.loads(json.dumps(L.get_state()))  # through real JSON
    R = ERSAC.from_state(state)
    names = L.observations.weights.names
    for x, row in zip(L.observations.points, L.observations.terms):
        R.observe(x, dict(zip(names, row)))
    return R


@pytest.mark.parametrize("cut,pending", [(3, False), (17, False), (20, True), (31, True)])
def test_resume_continues_bit_identically(cut: int, pending: bool) -> None:
    ref = make(seed=21)
    resumed = make(seed=21)
    noise = np.random.default_rng(0)
    costs = noise.standard_normal(60)
    for i in range(cut):
        x = resumed.ask()
        resumed.tell(x, J(x[0]) + r(x[0]) * costs[i])
    if pending:
        resumed.ask()
    resumed = _resume(resumed)
    for i in range(60):
        xa = ref.ask()
        if i < cut:
            ref.tell(xa, J(xa[0]) + r(xa[0]) * costs[i])
            continue
        xb = resumed.ask()
        np.testing.assert_array_equal(xa, xb)
        ua, ub = ref.tell(xa, J(xa[0]) + r(xa[0]) * costs[i]), resumed.tell(xb, J(xb[0]) + r(xb[0]) * costs[i])
        assert ua.to_dict() == ub.to_dict()
    assert ref.get_state() == resumed.get_state()


def test_resume_checks_the_observations() -> None:
    L = make(seed=2)
    episodes(L, 15)
    L.ask()
    state = L.get_state()
    R = ERSAC.from_state(state)
    for x, c in zip(L.observations.points[:10], L.observations.costs[:10]):
        R.observe(x, float(c))
    with pytest.raises(StateError):  # incomplete
        R.tell(R.ask(), 1.0)
    R2 = ERSAC.from_state(state)
    for x, c in zip(L.observations.points, L.observations.costs):
        R2.observe(x, float(c) + 1.0)  # different episodes
    with pytest.raises(StateError):
        R2.tell(R2.ask(), 1.0)
    for bad in ({**state, "format": "x"}, {**state, "rng": {"bit_generator": "MT19937"}}, {**state, "sigma": [-1.0]},
                {k: v for k, v in state.items() if k != "theta"}):
        with pytest.raises(StateError):
            ERSAC.from_state(bad)


def test_state_is_plain_json() -> None:
    L = make(seed=4)
    episodes(L, 14)
    L.ask()
    state = L.get_state()
    assert json.loads(json.dumps(state, allow_nan=False)) == state


# ----------------------------------------------------------------------------- bad input
def _bad_calls(L: ERSAC):
    x = L.ask()
    return [
        (NoPendingAskError, lambda: make().tell([0.2], 1.0)),
        (InvalidCostError, lambda: L.tell(x, float("nan"))),
        (InvalidCostError, lambda: L.tell(x, float("inf"))),
        (InvalidCostError, lambda: L.tell(x, "3")),
        (InvalidInputError, lambda: L.tell(np.append(x, 0.0), 1.0)),
        (InvalidInputError, lambda: L.tell([[x[0]]], 1.0)),
        (InvalidInputError, lambda: L.tell([float("nan")], 1.0)),
        (OutOfBoundsError, lambda: L.tell([1.5], 1.0)),
        (PendingMismatchError, lambda: L.tell(np.clip(x + 0.05, 0, 1) if x[0] < 0.9 else x - 0.05, 1.0)),
        (MissingTermError, lambda: L.tell(x, {})),
        (UnknownTermError, lambda: L.tell(x, {"cost": 1.0, "other": 2.0})),
        (OutOfBoundsError, lambda: L.observe([-0.1], 1.0)),
        (InvalidCostError, lambda: L.observe([0.1], float("nan"))),
        (InvalidInputError, lambda: L.critic_estimate([0.1, 0.2])),
        (OutOfBoundsError, lambda: L.critic([2.0])),
        (InvalidKappaError, lambda: L.select(kappa=float("nan"))),
        (UnknownTermError, lambda: L.reweight(CostWeights({"other": 1.0}))),
        (InvalidInputError, lambda: L.reweight({"cost": 1.0})),
    ]


def test_invalid_inputs_raise_typed_errors_and_change_nothing() -> None:
    L = make(seed=8)
    episodes(L, 16)
    calls = _bad_calls(L)
    before = snapshot(L)
    for exc, call in calls:
        with pytest.raises(exc) as info:
            call()
        assert isinstance(info.value, LearnerError)
        assert snapshot(L) == before, exc
    # and the learner still works
    x = L.ask()
    L.tell(x, 2.0)


@settings(max_examples=30, deadline=None)
@given(
    theta0=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=3),
    sigma=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.lists(st.floats(-1, 1), min_size=1, max_size=3)),
)
def test_constructor_validation(theta0, sigma) -> None:
    ok_theta = len(theta0) == 1 and math.isfinite(theta0[0]) and 0 <= theta0[0] <= 1
    s = np.atleast_1d(np.asarray(sigma, float))
    ok_sigma = s.size == 1 and math.isfinite(s[0]) and s[0] > 0
    if ok_theta and ok_sigma:
        make(theta0=theta0, sigma=sigma)
    else:
        with pytest.raises(LearnerError):
            make(theta0=theta0, sigma=sigma)


@pytest.mark.parametrize(
    "kw",
    [
        dict(bounds=[[1.0, 0.0]]),
        dict(bounds=[0.0, 1.0]),
        dict(bounds=[[0.0, float("inf")]]),
        dict(eta=0.0),
        dict(eta=float("nan")),
        dict(epsilon=-1.0),
        dict(lr_range=(0.5, 0.1)),
        dict(lr_range=(0.0, 0.1)),
        dict(seed=-1),
        dict(min_observations=2),
        dict(weights={"cost": 1.0}),
    ],
)
def test_bad_configuration_is_rejected(kw) -> None:
    with pytest.raises(InvalidInputError):
        make(**kw)


def test_critic_query_and_weighted_costs() -> None:
    w = CostWeights({"impact": 1.0, "energy": 0.5})
    L = make(weights=w, critic=CriticConfig(epsilon=0.3, min_neighbours=8))
    noise = np.random.default_rng(0)
    for _ in range(20):
        x = L.ask()
        L.tell(x, {"impact": J(x[0]) + r(x[0]) * noise.standard_normal(), "energy": 2.0 * x[0]})
    Jt, rt = L.critic(L.theta)
    e = L.critic_estimate(L.theta, kappa=2.0)
    assert (e.J, e.r) == (Jt, rt) and e.F == pytest.approx(Jt + 2.0 * rt)
    with pytest.raises(MissingTermError):
        L.tell(L.ask(), 1.0)  # a bare number needs single-term weights


def test_theta_setter_and_discard():
    from ersac_hil.learner import PendingAskError
    lrn = ERSAC([0.5], [0.1], 0.1, 0.0, 0.3, [[0.0, 1.0]], seed=3)
    lrn.theta = [0.2]
    assert lrn.theta.tolist() == [0.2]
    with pytest.raises(OutOfBoundsError):
        lrn.theta = [1.5]
    assert lrn.theta.tolist() == [0.2]
    first = lrn.ask()
    with pytest.raises(PendingAskError):
        lrn.theta = [0.4]
    assert lrn.theta.tolist() == [0.2]
    lrn.discard()
    assert lrn.pending is None
    second = lrn.ask()
    assert second.tolist() != first.tolist()  # a fresh draw, the RNG moved on
