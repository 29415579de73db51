"""ERSAC robustness: a critic that cannot fit skips the update, the move guard bounds a
single update, a broken fit record does not block resume, interleaved offline search."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ersac_hil.learner import ERSAC, InvalidInputError, StateError
from ersac_hil.learner.ersac import GreedyRule

BOUNDS = [[0.0, 1.0]]


def J(t: float) -> float:
    return 3.0 - 2.4 * t + 1.5 * t * t


def r(t: float) -> float:
    return 0.1 + 1.2 * t * t


def make(**kw) -> ERSAC:
    args = dict(theta0=[0.3], sigma=0.1, eta=0.1, kappa=0.0, epsilon=0.3, bounds=BOUNDS, seed=3)
    args.update(kw)
    return ERSAC(**args)


def run(L: ERSAC, n: int, cost=None, noise_seed: int = 1):  # noqa: ANN001
    noise = np.random.default_rng(noise_seed)
    out = []
    for i in range(n):
        x = L.ask()
        c = J(x[0]) + r(x[0]) * noise.standard_normal()
        out.append(L.tell(x, c if cost is None else cost(i, c)))
    return out


def resume(L: ERSAC) -> ERSAC:
    R = ERSAC.from_state(json.loads(json.dumps(L.get_state())))
    for x, c in zip(L.observations.points, L.observations.costs):
        R.observe(x, float(c))
    return R


def test_a_critic_that_cannot_fit_skips_the_update_and_the_run_goes_on() -> None:
    L = make()
    # episode 20 reports a cost whose square overflows: no GP/VHGP fit of any neighbourhood
    # holding it is numerically possible
    ups = run(L, 40, cost=lambda i, c: 1e200 if i == 20 else c)
    assert all(u.skipped is None for u in ups[:20])
    skipped = [u for u in ups[20:] if u.skipped is not None]
    assert skipped and "critic fit failed" in skipped[0].skipped
    for u in skipped:
        np.testing.assert_array_equal(u.theta_before, u.theta_after)
        assert u.J_tilde is None and u.step_size == 0.0 and not u.warmup
    assert L.n_observations == 40 and L.n_updates == 40  # every observation kept
    # the run is resumable and continues exactly like the uninterrupted learner
    R = resume(L)
    xa, xb = L.ask(), R.ask()
    np.testing.assert_array_equal(xa, xb)
    assert L.tell(xa, 2.0).to_dict() == R.tell(xb, 2.0).to_dict()


def test_a_fit_record_that_cannot_be_rebuilt_does_not_block_resume() -> None:
    L = make()
    run(L, 20)
    state = json.loads(json.dumps(L.get_state()))
    state["last_fit"]["params"]["log_lambda"] = state["last_fit"]["params"]["log_lambda"][:-1]
    R = ERSAC.from_state(state)
    for x, c in zip(L.observations.points, L.observations.costs):
        R.observe(x, float(c))
    u = R.tell(R.ask(), 2.0)
    assert u.skipped is None and u.J_tilde is not None


def test_the_move_guard_bounds_an_outlier_update() -> None:
    """An injected outlier cost at a 2.5-sigma perturbation: without the guard the paper's
    step throws theta by many sigma; with max_step = 3 no coordinate moves more than 3 sigma,
    the step keeps its direction and the scale is recorded."""
    moves = {}
    for guard in (None, 3.0):
        L = make(max_step=guard, sigma=0.05, theta0=[0.5], lr_range=(0.01, 0.5))
        run(L, 20)
        L._pending = np.array([0.5 * 0 + L.theta[0] + 2.5 * 0.05])  # a 2.5-sigma draw
        u = L.tell(L.pending, 60.0)  # an outlier episode
        moves[guard] = (u.theta_after - u.theta_before)[0] / 0.05
        if guard is None:
            assert u.step_scale == 1.0
        else:
            assert u.step_scale < 1.0 and u.to_dict()["step_scale"] == u.step_scale
    assert abs(moves[None]) > 6.0 or moves[None] <= -L.theta[0] / 0.05  # thrown (or clipped at the bound)
    assert abs(moves[3.0]) <= 3.0 + 1e-9 and np.sign(moves[3.0]) == np.sign(moves[None])


def test_interleaved_search_moves_to_the_local_argmin_every_k_updates() -> None:
    L = make(interleave_every=4, kappa=2.0)
    ups = run(L, 30)
    real = [u for u in ups if not u.warmup]
    # only every 4th update may move offline, and only where the critic is confident
    assert all((u.index + 1) % 4 == 0 for u in real if u.offline)
    assert any(u.offline for u in real)
    for u in real:
        if u.offline:  # a local greedy move: within epsilon / 2 of a point near theta
            near = L.observations.points[:u.index + 1, 0]
            assert np.min(np.abs(near - u.theta_after[0])) <= 0.3 / 2 + 1e-9
            assert abs(u.theta_after[0] - u.theta_before[0]) <= 2 * 0.3 + 1e-9
    R = resume(L)  # the option survives the state round trip
    assert R.get_state()["interleave_every"] == 4
    xa, xb = L.ask(), R.ask()
    assert L.tell(xa, 2.0).to_dict() == R.tell(xb, 2.0).to_dict()


def test_interleaved_moves_leave_sub_sigma_moves_to_the_gradient_step() -> None:
    """Greedy moves go at least one sigma (0.1) from where the gradient step went (without
    the rule seeds 1 and 4 make moves of less than a sigma; seed 3 moves with it)."""
    moves = [u for seed in (1, 3, 4) for u in run(make(interleave_every=1, kappa=2.0, seed=seed), 30) if u.offline]
    assert moves
    for u in moves:
        stepped = np.clip(u.theta_before - u.step_scale * u.step_size * u.td_error * u.z, *BOUNDS[0])
        assert abs(u.theta_after[0] - stepped[0]) >= 0.1 - 1e-9


def test_a_trust_region_step_moves_at_most_its_radius_along_the_critic_and_survives_resume() -> None:
    """GreedyRule(around="theta"): every offline move stays within radius sigma of the gradient
    step's theta and goes where this update's F~ is lower; z 0 moves whenever it is lower,
    so moves are frequent; the rule is part of the state (resume continues bit for bit)."""
    rule = GreedyRule(z=0.0, radius=1.0, min_move=0.0, around="theta")
    L = make(interleave_every=1, kappa=2.0, greedy=rule)
    ups = [u for u in run(L, 30) if not u.warmup]
    moves = [u for u in ups if u.offline]
    assert len(moves) >= len(ups) // 2
    for u in moves:
        stepped = np.clip(u.theta_before - u.step_scale * u.step_size * u.td_error * u.z, *BOUNDS[0])
        assert abs(u.theta_after[0] - stepped[0]) <= 0.1 + 1e-9
    assert L.get_state()["greedy"] == {"z": 0.0, "radius": 1.0, "min_move": 0.0, "around": "theta"}
    R = resume(L)
    assert R.greedy == rule
    xa, xb = L.ask(), R.ask()
    assert L.tell(xa, 2.0).to_dict() == R.tell(xb, 2.0).to_dict()


def test_a_state_saved_before_the_greedy_rule_resumes_with_the_gated_move() -> None:
    L = make(interleave_every=1)
    run(L, 12)
    state = json.loads(json.dumps(L.get_state()))
    del state["greedy"]
    assert resume_from(state, L).greedy == GreedyRule()
    state["greedy"] = {"z": 1.0, "wrong": 2}
    with pytest.raises(StateError):
        ERSAC.from_state(state)


def resume_from(state: dict, L: ERSAC) -> ERSAC:
    R = ERSAC.from_state(state)
    for x, c in zip(L.observations.points, L.observations.costs):
        R.observe(x, float(c))
    return R


@pytest.mark.parametrize("kw", [dict(z=-1.0), dict(z=float("nan")), dict(radius=0.0), dict(min_move=-0.1),
                                dict(around="everywhere"), dict(z=True)])
def test_a_bad_greedy_rule_is_refused(kw) -> None:  # noqa: ANN001
    with pytest.raises(InvalidInputError):
        GreedyRule(**kw)


@pytest.mark.parametrize("kw", [dict(max_step=0.0), dict(max_step=-1.0), dict(max_step=float("nan")),
                                dict(interleave_every=-1), dict(interleave_every=1.5), dict(interleave_every=True)])
def test_bad_options_are_refused(kw) -> None:  # noqa: ANN001
    with pytest.raises(InvalidInputError):
        make(**kw)


@pytest.mark.parametrize("seed", [0, 7])
def test_the_td_baseline_stays_within_the_costs_it_was_fitted_to(seed: int) -> None:
    """Costs of two modes (4.5 or 38 at random) in 7-D: a near-interpolating fit rings, and
    without the clip J~(theta) leaves the costs' range (these seeds: -4.1 and 40.4 at the 11th
    update); with it (the default) every update's J~ is inside [min, max] of its fit's costs."""
    def costs(clip: bool) -> tuple[list, list]:
        from ersac_hil.critic import CriticConfig

        L = ERSAC(np.full(7, 1.0), 0.075, 0.5, 0.0, 0.2625, [[0.0, 2.0]] * 7, seed=seed,
                  critic=CriticConfig(epsilon=1.0, clip_mean=clip))
        noise = np.random.default_rng(seed)
        J, ranges = [], []
        for _ in range(12):
            x = L.ask()
            u = L.tell(x, (4.5 if noise.random() < 0.3 else 38.0) + 0.3 * noise.standard_normal())
            if u.J_tilde is not None:
                y = L.observations.costs[L.local_critic.neighbourhood(u.theta_before)]
                J.append(u.J_tilde)
                ranges.append((y.min(), y.max()))
        return J, ranges

    J, ranges = costs(False)
    assert any(j < lo - 1 or j > hi + 1 for j, (lo, hi) in zip(J, ranges))
    J, ranges = costs(True)
    assert all(lo <= j <= hi for j, (lo, hi) in zip(J, ranges))
