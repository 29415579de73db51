"""bench/learner.py's peers (CMA-ES, MV-BO, random search with re-evaluation), as
``bench/tasks.py peers`` runs them on the real tasks: within the episode budget, and a
candidate the system refuses (``Infeasible``, no episode run) is replaced, never scored."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[2] / "bench" / "learner.py"
_spec = importlib.util.spec_from_file_location("bench_learner", _PATH)
peers = sys.modules["bench_learner"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(peers)

RUNS = {"CMA-ES": peers.run_cma, "MV-BO": peers.run_mvbo, "random": peers.run_random}


def _problem(budget: int, feasible, evaluated: list, refused: list):  # noqa: ANN001, ANN202
    """A 2-D bowl at (0.7, 0.3) whose sample refuses (raises ``Infeasible``) outside
    ``feasible``, recording every scored and every refused point."""
    noise = np.random.default_rng(0)

    def sample(x: np.ndarray, _noise: object, k: int | None) -> np.ndarray:
        if not feasible(x):
            refused.append(np.array(x))
            raise peers.Infeasible("beyond the limits")
        evaluated.extend([np.array(x)] * (k or 1))
        return float(np.sum((x - [0.7, 0.3]) ** 2)) + 0.01 * noise.standard_normal(k or 1)

    nan = lambda X: np.full(len(X), np.nan)  # noqa: E731
    return peers.Problem("refusing-bowl", np.array([[0.0, 1.0]] * 2), np.array([0.2, 0.2]), nan, nan, budget,
                         0.1, 0.1, 0.3, 10, 10, sample=sample)


@pytest.mark.parametrize("method", list(RUNS))
@pytest.mark.parametrize("budget", [30, 45])
def test_peers_stay_within_the_budget(method: str, budget: int) -> None:
    evaluated: list = []
    traj, _ = RUNS[method](_problem(budget, lambda x: True, evaluated, []), 0.0, 3)
    assert traj.shape == (budget, 2) and np.isfinite(traj).all()
    assert budget - peers.REPEATS < len(evaluated) <= budget


@pytest.mark.parametrize("method", list(RUNS))
def test_a_refused_candidate_is_redrawn_not_scored(method: str) -> None:
    """Most of the box refused: every episode is spent on allowed points, the budget is still
    used, and the recommended policy of MV-BO and random search (an evaluated point) is allowed."""
    allowed = lambda x: x[1] < 0.35  # noqa: E731
    evaluated, refused = [], []
    traj, _ = RUNS[method](_problem(40, allowed, evaluated, refused), 0.0, 5)
    assert refused, "the test needs a refused candidate"
    assert all(allowed(x) for x in evaluated)
    assert len(evaluated) == 40
    if method != "CMA-ES":  # CMA-ES recommends its distribution's mean, which is not evaluated
        assert all(allowed(x) for x in traj)


def test_a_box_refused_everywhere_ends_in_one_error() -> None:
    with pytest.raises(RuntimeError, match="in a row were refused"):
        peers.run_random(_problem(20, lambda x: bool(np.all(x == [0.2, 0.2])), [], []), 0.0, 1)
