"""reproduce's figures: the lifting figure (the paper's Fig. 4) lays many run seeds out as a
grid that reads at page width, not as a strip of narrow panels."""
from __future__ import annotations

import math

import matplotlib.image as mpimg
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.daemon.config import TASK_DEFAULTS
from ersac_hil.reproduce import figures, lifting
from ersac_hil.reproduce.trials import Trial, TrialSpec
from protocol.zenoh import get_task
from protocol.zenoh.tasks import LIFTING_GOAL_HEIGHT_M


@given(st.integers(1, 40), st.integers(1, 8))
def test_panel_grid_fills_rows_of_at_most_the_given_columns(n, most):
    rows, cols = figures.panel_grid(n, most)
    assert cols <= most and rows * cols >= n
    assert rows == math.ceil(n / most)        # as few rows as the columns allow
    assert (rows - 1) * cols < n              # no empty row
    assert rows * cols - n < rows             # the rows within one panel of each other


def test_ten_seeds_are_two_rows_of_five():
    assert figures.panel_grid(10) == (2, 5)
    assert figures.panel_grid(7) == (2, 4)
    assert figures.panel_grid(3) == (1, 3)


def _trial(seed: int, i: int, height: float) -> Trial:
    spec = TrialSpec("lifting", TASK_DEFAULTS["lifting"].theta0, 1000 * seed + i)
    terms = {name: 0.5 + 0.01 * i for name in get_task("lifting").default_weights}
    return Trial(spec, "ok", terms, {"bottle_dropped": False, "fallen": False},
                 {"final_bottle_height_m": height}, "", 1.0)


def _columns(seeds: int) -> dict:
    return {s: [(label, [_trial(s, i, LIFTING_GOAL_HEIGHT_M if i % 3 else 0.9) for i in range(10)])
                for label in ("initial", "after 15", "after 30")] for s in range(1, seeds + 1)}


@pytest.mark.parametrize("seeds", [10, 7, 3])
def test_fig4_of_many_seeds_is_not_a_strip(tmp_path, seeds):
    path = tmp_path / "fig4.png"
    figures.fig4(_columns(seeds), lifting.success, path)
    height, width = mpimg.imread(path).shape[:2]
    rows, cols = figures.panel_grid(seeds)
    # a panel keeps the width a 3-box panel needs, and the figure is at most ~2:1 (the
    # 1 x 10 strip it replaces was 8:1, its panels a tenth of the page wide)
    assert width / cols >= 250 and width / height <= 2.5, (width, height)
    assert height / rows >= 300
