"""The reproduce statistics: the landscape's argmins and bootstrap errors, the paired test,
Welch's test and the variance test, on data whose answer is known."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats as sps

from ersac_hil.reproduce.stats import Landscape, describe, paired, variance_drop, welch


def _landscape(means, stds, n=200, seed=0) -> Landscape:
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(n)  # common random numbers: the same seed at every theta
    J = np.array([m + s * z for m, s in zip(means, stds)])
    zeros = np.zeros_like(J)
    return Landscape.from_arrays(np.linspace(0, 1, len(means)), J, zeros, zeros, ("a",), J[..., None],
                                 n_boot=300)


def test_risk_averse_optimum_is_where_the_spread_is_small():
    land = _landscape(means=[10, 8, 6, 5, 4.5], stds=[0.5, 0.5, 0.5, 1.5, 3.0])
    assert land.theta_min(0.0) == 1.0 and land.theta_min(2.0) == 0.5
    s = land.summary()
    assert s["F2_gap"] == pytest.approx(land.objective(2.0)[4] - land.objective(2.0)[2])
    assert s["F2_gap_in_se"] > 3
    assert len(land.rows()) == 5 and "argmin mean + 2 std: theta 0.50" in land.markdown()


def test_the_table_names_each_column_once_even_for_a_damage_term():
    rng = np.random.default_rng(1)
    J = rng.normal(5.0, 1.0, (3, 20))
    dmg = (rng.random((3, 20)) < 0.3).astype(float)
    land = Landscape.from_arrays(np.linspace(0, 1, 3), J, dmg, np.zeros_like(J), ("damage", "power"),
                                 np.stack([dmg, J], axis=-1), n_boot=50)
    head = [c.strip() for c in land.markdown().splitlines()[0].strip("|").split("|")]
    assert len(head) == len(set(head)) and "damage rate" in head and "mean damage" in head


def test_the_same_optimum_has_no_gap():
    land = _landscape(means=[3, 2, 1], stds=[1, 1, 1])
    assert land.theta_min(0.0) == land.theta_min(2.0) == 1.0
    assert land.summary()["F2_gap"] == 0.0 and land.summary()["F2_gap_in_se"] == 0.0


def test_bootstrap_error_of_the_mean_is_the_standard_error():
    land = _landscape(means=[0.0], stds=[2.0], n=400)
    assert land.se(0.0)[0] == pytest.approx(2.0 / math.sqrt(400), rel=0.2)


def test_a_landscape_needs_two_episodes_per_theta():
    with pytest.raises(ValueError, match="2 episodes"):
        Landscape.from_arrays([0.0], [[1.0]], [[0]], [[0]], ("a",), [[[1.0]]])


def test_paired_counts_lower_pairs_and_tests_their_median():
    k2 = np.array([0.3, 0.35, 0.4, 0.3, 0.45, 0.38, 0.32, 0.41, 0.36, 0.34])
    k0 = k2 + np.array([0.2, 0.15, 0.3, 0.25, -0.05, 0.22, 0.18, 0.1, 0.3, 0.12])
    p = paired(k2, k0)
    assert p.n_lower == 9 and p.median_diff == pytest.approx(np.median(k0 - k2))
    assert p.wilcoxon_p == pytest.approx(sps.wilcoxon(k0 - k2, alternative="greater").pvalue)
    assert p.wilcoxon_p < 0.01
    assert math.isnan(paired([0.5, 0.5], [0.5, 0.5]).wilcoxon_p)  # no non-zero difference


@settings(deadline=None)  # scipy's first call is slow on a loaded machine
@given(st.lists(st.floats(-100, 100), min_size=3, max_size=20), st.floats(0.5, 50))
def test_welch_is_one_sided_towards_a_lower_mean(before, shift):
    before = np.asarray(before) + np.linspace(0, 1, len(before))  # never constant
    after = before - shift
    assert welch(before, after) < 0.5 < welch(after, before)


def test_variance_drop_is_the_f_test():
    rng = np.random.default_rng(1)
    a, b = rng.normal(0, 3, 10), rng.normal(0, 0.5, 10)
    f = np.var(b, ddof=1) / np.var(a, ddof=1)
    assert variance_drop(a, b) == pytest.approx(sps.f.cdf(f, 9, 9)) and variance_drop(a, b) < 0.01
    assert variance_drop(b, a) > 0.99
    assert math.isnan(variance_drop([1.0], [1.0, 2.0])) and math.isnan(welch([1.0], [2.0, 3.0]))


def test_describe_has_the_mu_plus_two_sigma_line():
    d = describe([1.0, 2.0, 3.0])
    assert d["mean"] == 2.0 and d["std"] == 1.0 and d["mu_2sigma"] == 4.0 and d["n"] == 3
    assert math.isnan(describe([])["mean"])


def test_the_gap_error_is_paired_over_seeds_common_to_every_theta():
    """Seed j is the same scenario at every theta (common random numbers): its draw moves the
    F2 of both optima together, so the paired bootstrap SE of their difference is far below the
    unpaired one, and a gap resolved by the pairing is reported as resolved."""
    land = _landscape(means=[10.0, 5.5, 4.5], stds=[3.0, 2.5, 3.2])
    i0, i2 = land.argmin(0.0), land.argmin(2.0)
    assert (land.theta_min(0.0), land.theta_min(2.0)) == (1.0, 0.5)
    gap, se = land.gap(2.0)
    unpaired = math.hypot(land.se(2.0)[i0], land.se(2.0)[i2])
    assert se < 0.3 * unpaired and gap / se > 3 > gap / unpaired
