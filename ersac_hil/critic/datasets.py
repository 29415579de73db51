"""Synthetic heteroscedastic regression sets used to validate the VHGP: Goldberg, Williams and
Yuan, the sets of Lazaro-Gredilla & Titsias (ICML 2011) with their sizes (60, 200, 200).

Each generator returns a `HeteroscedasticSet` of n points drawn with the given numpy
Generator, plus the true mean and noise std as functions (for recovery checks).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Fn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class HeteroscedasticSet:
    """x (n,), y (n,), mean(x) and std(x) the true functions, domain (lo, hi)."""

    name: str
    x: np.ndarray
    y: np.ndarray
    mean: Fn
    std: Fn
    domain: tuple[float, float]

    @property
    def X(self) -> np.ndarray:
        """Inputs as a column, (n, 1)."""
        return self.x[:, None]


def _make(name: str, n: int, rng: np.random.Generator, domain: tuple[float, float], mean: Fn, std: Fn) -> HeteroscedasticSet:
    x = rng.uniform(domain[0], domain[1], size=n)
    y = mean(x) + std(x) * rng.standard_normal(n)
    return HeteroscedasticSet(name, x, y, mean, std, domain)


def goldberg(rng: np.random.Generator, n: int = 60) -> HeteroscedasticSet:
    """x ~ U(0, 1), mean 2 sin(2 pi x), std x + 0.5."""
    return _make("goldberg", n, rng, (0.0, 1.0), lambda x: 2.0 * np.sin(2.0 * np.pi * x), lambda x: x + 0.5)


def williams(rng: np.random.Generator, n: int = 200) -> HeteroscedasticSet:
    """x ~ U(0, pi), mean sin(2.5x) sin(1.5x), std 0.01 + 0.25 (1 - sin(2.5x))^2."""
    return _make(
        "williams",
        n,
        rng,
        (0.0, float(np.pi)),
        lambda x: np.sin(2.5 * x) * np.sin(1.5 * x),
        lambda x: 0.01 + 0.25 * (1.0 - np.sin(2.5 * x)) ** 2,
    )


def yuan(rng: np.random.Generator, n: int = 200) -> HeteroscedasticSet:
    """x ~ U(0, 1), mean 2 (exp(-30 (x - 0.25)^2) + sin(2 pi x^2)) - 2, std exp(sin(2 pi x))."""
    return _make(
        "yuan",
        n,
        rng,
        (0.0, 1.0),
        lambda x: 2.0 * (np.exp(-30.0 * (x - 0.25) ** 2) + np.sin(2.0 * np.pi * x**2)) - 2.0,
        lambda x: np.exp(np.sin(2.0 * np.pi * x)),
    )


ALL: dict[str, Callable[..., HeteroscedasticSet]] = {"goldberg": goldberg, "williams": williams, "yuan": yuan}


# Risk-averse BO benchmarks (Makarova et al. 2021, RAHBO), as costs; inputs X (m, d) -> (m,).
def sigmoid(v: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-v))


def rahbo_sine_cost(X: np.ndarray) -> np.ndarray:
    """-sin(2 pi x) on [0, 2]: equal minima at 0.25 (quiet) and 1.25 (noisy). X (m, 1)."""
    return -np.sin(2.0 * np.pi * X[:, 0])


def rahbo_sine_std(X: np.ndarray, s: float = 1.0) -> np.ndarray:
    """sigmoid(30 (x - 1)) s + 0.1. X (m, 1)."""
    return sigmoid(30.0 * (X[:, 0] - 1.0)) * s + 0.1


def branin(X: np.ndarray) -> np.ndarray:
    """The Branin function on [-5, 10] x [0, 15] (three minima of 0.398). X (m, 2)."""
    x1, x2 = X[:, 0], X[:, 1]
    b, c, t = 5.1 / (4 * np.pi**2), 5 / np.pi, 1 / (8 * np.pi)
    return (x2 - b * x1**2 + c * x1 - 6) ** 2 + 10 * (1 - t) * np.cos(x1) + 10


def branin_std(X: np.ndarray, s: float = 1.0) -> np.ndarray:
    """(sigmoid(2 (x1 - 3.2)) s + 0.2)(sigmoid(2 x2) s + 0.2). X (m, 2)."""
    return (sigmoid(2.0 * (X[:, 0] - 3.2)) * s + 0.2) * (sigmoid(2.0 * X[:, 1]) * s + 0.2)


# A bracing-shaped cost with a Bernoulli jump (the shape of the bracing task's landscape): the
# mean falls with theta, damage adds DAMAGE_COST with a probability that ramps (piecewise
# linear) from 0 at 0.35 to 0.17 at 0.7 and 0.8 at 0.85, on top of Gaussian noise of std
# JUMP_BASE_STD.  argmin of the mean 0.70, of the mean + 2 std 0.35.  X (m, 1) on [0, 1].
DAMAGE_COST = 90.0
JUMP_BASE_STD = 5.0


def damage_probability(t: np.ndarray) -> np.ndarray:
    return np.interp(t, [0.0, 0.35, 0.7, 0.85, 1.0], [0.0, 0.0, 0.17, 0.8, 0.95])


def jump_cost_mean(X: np.ndarray) -> np.ndarray:
    """100 - 120 t + DAMAGE_COST p(t)."""
    return 100.0 - 120.0 * X[:, 0] + DAMAGE_COST * damage_probability(X[:, 0])


def jump_cost_std(X: np.ndarray) -> np.ndarray:
    """sqrt(JUMP_BASE_STD^2 + DAMAGE_COST^2 p (1 - p))."""
    q = damage_probability(X[:, 0])
    return np.sqrt(JUMP_BASE_STD**2 + DAMAGE_COST**2 * q * (1.0 - q))


def jump_cost_sample(X: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One noisy cost per row of X (m, 1): (m,)."""
    t = X[:, 0]
    base = 100.0 - 120.0 * t + JUMP_BASE_STD * rng.standard_normal(t.size)
    return base + DAMAGE_COST * (rng.uniform(size=t.size) < damage_probability(t))
