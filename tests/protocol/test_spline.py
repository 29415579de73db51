import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from protocol.can.spline import hermite_sample

knots = st.integers(2, 8).flatmap(lambda n: st.tuples(
    st.lists(st.floats(0.05, 2.0), min_size=n - 1, max_size=n - 1),
    st.lists(st.floats(-3.0, 3.0), min_size=n, max_size=n),
    st.lists(st.floats(-5.0, 5.0), min_size=n, max_size=n)))


@given(knots)
def test_passes_through_knots_and_rests_outside(spec):
    gaps, pos, vel = spec
    times = np.concatenate([[0.0], np.cumsum(gaps)])
    q_k, v_k = np.array(pos)[:, None], np.array(vel)[:, None]
    q, qd = hermite_sample(times, q_k, v_k, times[:-1])
    np.testing.assert_allclose(q[:, 0], pos[:-1], atol=1e-9)
    np.testing.assert_allclose(qd[:, 0], vel[:-1], atol=1e-9)
    q, qd = hermite_sample(times, q_k, v_k, [-1.0, times[-1], times[-1] + 1.0])
    np.testing.assert_allclose(q[:, 0], [pos[0], pos[-1], pos[-1]])
    np.testing.assert_allclose(qd[:, 0], 0.0)


@given(knots)
def test_velocity_is_the_derivative_of_position(spec):
    gaps, pos, vel = spec
    times = np.concatenate([[0.0], np.cumsum(gaps)])
    t = np.linspace(0.0, times[-1], 400)[1:-1]
    t = t[np.min(np.abs(t[:, None] - times[None, :]), axis=1) > 2e-3]  # not across a knot
    eps = 1e-6
    qp, _ = hermite_sample(times, np.array(pos)[:, None], np.array(vel)[:, None], t + eps)
    qm, _ = hermite_sample(times, np.array(pos)[:, None], np.array(vel)[:, None], t - eps)
    _, qd = hermite_sample(times, np.array(pos)[:, None], np.array(vel)[:, None], t)
    np.testing.assert_allclose((qp - qm) / (2 * eps), qd, atol=1e-4 * (1 + np.abs(qd).max()))
