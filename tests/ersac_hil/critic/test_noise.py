"""The log-linear noise model and the VHGP's leave-one-out residuals it is fitted to."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ersac_hil.critic import VHGP
from ersac_hil.critic.noise import fit_log_linear, pseudo_count


def test_recovers_a_log_linear_noise() -> None:
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (4000, 2))
    a, b = np.log(0.3**2), np.array([1.5, -0.8])
    e = np.exp(0.5 * (a + X @ b)) * rng.standard_normal(4000)
    m = fit_log_linear(X, e, np.zeros(4000), np.full(2, 100.0))
    c = X.mean(0)
    np.testing.assert_allclose(m.coef[1:], b, atol=0.1)
    assert m.coef[0] == pytest.approx(a + c @ b, abs=0.1)
    # the posterior std of the slope is the Cramer-Rao figure sqrt(2 / (n var(x))) here
    np.testing.assert_allclose(np.sqrt(np.diag(m.cov)[1:]), np.sqrt(2 / (4000 * X.var(0))), rtol=0.1)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), d=st.integers(1, 4))
def test_gradients_match_finite_differences(seed: int, d: int) -> None:
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 1, (20, d))
    m = fit_log_linear(X, rng.standard_normal(20), rng.uniform(0, 0.1, 20), np.full(d, 3.0))
    x = rng.uniform(0, 1, (1, d))
    gm, gv = m.gradient(x)
    h = 1e-6
    for k in range(d):
        dx = np.zeros((1, d))
        dx[0, k] = h
        (m1, v1), (m0, v0) = m.predict(x + dx), m.predict(x - dx)
        assert gm[0, k] == pytest.approx((m1 - m0)[0] / (2 * h), rel=1e-5, abs=1e-8)
        assert gv[0, k] == pytest.approx((v1 - v0)[0] / (2 * h), rel=1e-5, abs=1e-8)


def test_vhgp_leave_one_out_matches_refitting_without_the_point() -> None:
    """e_i and v_i against the posterior of the same model (hyperparameters, lambdas and so
    R held) built on the other n - 1 points."""
    rng = np.random.default_rng(5)
    X = rng.uniform(0, 1, (25, 1))
    y = np.sin(6 * X[:, 0]) + (0.1 + 0.3 * X[:, 0]) * rng.standard_normal(25)
    model = VHGP().fit(X, y)
    e, v = model.loo(noise_floor=0.0)
    from ersac_hil.critic.kernels import se_ard

    n = 25
    p = model.params
    lf, lsf = p.kernel[:1], p.kernel[1]
    std = model._std
    ys = std.apply(y)
    Kf = se_ard(X, X, lf, lsf)
    R = model._R
    for i in (0, 7, 24):
        keep = np.arange(n) != i
        K = Kf[np.ix_(keep, keep)] + np.diag(R[keep] + 1e-8)
        k = Kf[i, keep]
        mean = k @ np.linalg.solve(K, ys[keep])
        var = Kf[i, i] - k @ np.linalg.solve(K, k)
        assert e[i] == pytest.approx(std.scale * (ys[i] - mean), rel=1e-6)
        assert v[i] == pytest.approx(std.scale**2 * (var + 1e-8), rel=1e-5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), d=st.integers(1, 7), data=st.data())
def test_the_small_sample_prior_bounds_the_level_from_below(seed: int, d: int, data: st.DataObject) -> None:
    """With m0 pseudo-residuals of variance S, exp(g(c)) >= m0 S / (m0 + n) at the centre
    c, whatever the residuals (fit_log_linear's doc)."""
    n = data.draw(st.integers(3, 2 * (d + 1) - 1))
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 1, (n, d))
    e = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 2)
    S = 10.0 ** rng.uniform(-2, 4)
    m0 = pseudo_count(n, d)
    assert m0 == 2 * (d + 1) - n > 0
    m = fit_log_linear(X, e, rng.uniform(0, 0.1, n), np.full(d, 3.0), spread=S, pseudo=m0)
    g_c, _ = m.predict(X.mean(0)[None])
    assert np.exp(g_c[0]) >= (1 - 1e-6) * m0 * S / (m0 + n)
    assert pseudo_count(2 * (d + 1), d) == 0  # none from 2 (d + 1) points on
