"""Costs as weighted sums of named terms, and the learner's observations.

An episode returns named cost terms (e.g. {"impact": .., "energy": .., "damage": ..}); the
scalar cost the learner optimises is sum_k w_k t_k for a `CostWeights` mapping.  `Observations`
keeps every observation's terms, so changing the weights (a new risk context: energy-averse,
translation-averse) recomputes every stored cost exactly: the sum is always accumulated in
the sorted order of the names, element-wise, so a cost recomputed from its terms is
bit-identical to one computed when the observation arrived.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator, Mapping
import numpy as np

from protocol.zenoh.tasks import weighted_total

from .errors import InvalidCostError, InvalidInputError, MissingTermError, UnknownTermError

DEFAULT_TERM = "cost"


def finite_real(value: object, what: str, exc: type[Exception] = InvalidInputError) -> float:
    """``value`` as a finite float, else ``exc`` naming ``what`` (bools are not numbers here)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise exc(f"{what} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise exc(f"{what} must be finite, got {v}")
    return v


class CostWeights(Mapping[str, float]):
    """Frozen mapping term name -> weight (finite real).  Iterates in sorted name order."""

    __slots__ = ("_items",)

    def __init__(self, weights: Mapping[str, float]) -> None:
        if not isinstance(weights, Mapping) or len(weights) == 0:
            raise InvalidInputError("CostWeights needs a non-empty mapping name -> weight")
        items = []
        for name, w in weights.items():
            if not isinstance(name, str) or not name:
                raise InvalidInputError(f"cost term names must be non-empty strings, got {name!r}")
            items.append((name, finite_real(w, f"weight of {name!r}")))
        self._items: tuple[tuple[str, float], ...] = tuple(sorted(items))

    # Mapping protocol
    def __getitem__(self, name: str) -> float:
        for k, w in self._items:
            if k == name:
                return w
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return (k for k, _ in self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __hash__(self) -> int:
        return hash(self._items)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, CostWeights):
            return self._items == other._items
        return NotImplemented

    def __repr__(self) -> str:
        return f"CostWeights({dict(self._items)!r})"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self._items)

    @property
    def vector(self) -> np.ndarray:
        """Weights in name order, (K,)."""
        return np.array([w for _, w in self._items], dtype=float)

    def to_dict(self) -> dict[str, float]:
        return dict(self._items)

    def check_names(self, names: object) -> None:
        """Raise Unknown/MissingTermError unless `names` are exactly these weights' names."""
        given = set(names)  # type: ignore[call-overload]
        mine = set(self.names)
        unknown = sorted(str(n) for n in given - mine)
        missing = sorted(mine - given)
        if unknown:
            raise UnknownTermError(f"unknown cost terms {unknown}; known: {sorted(mine)}")
        if missing:
            raise MissingTermError(f"missing cost terms {missing}")

    def term_vector(self, terms: Mapping[str, float] | float) -> np.ndarray:
        """Validated term values in name order, (K,).  A bare number is accepted when there
        is exactly one term."""
        if not isinstance(terms, Mapping):
            if len(self._items) != 1:
                raise MissingTermError(f"a bare cost needs exactly one weighted term; terms are {list(self.names)}")
            return np.array([finite_real(terms, "cost", InvalidCostError)])
        self.check_names(terms.keys())
        return np.array([finite_real(terms[k], f"cost term {k!r}", InvalidCostError) for k in self.names])

    def combine_rows(self, T: np.ndarray) -> np.ndarray:
        """sum_k w_k T[:, k], accumulated in name order (the contract's `weighted_total`, so
        a cost is bit-identical to the agent's `total_cost`).  T (N, K) -> (N,)."""
        columns = {name: T[:, k] for k, (name, _) in enumerate(self._items)}
        return np.asarray(weighted_total(columns, dict(self._items)), dtype=float)

    def combine(self, terms: Mapping[str, float] | float) -> float:
        """The scalar cost of one observation's terms."""
        return float(self.combine_rows(self.term_vector(terms)[None, :])[0])


class Observations:
    """Append-only observations: points (N, d), terms (N, K), costs (N,) under `weights`.

    Implements the critic's CriticData protocol (`points`, `costs`)."""

    def __init__(self, dim: int, weights: CostWeights | None = None) -> None:
        if not isinstance(dim, numbers.Integral) or dim < 1:
            raise InvalidInputError(f"dim must be a positive integer, got {dim!r}")
        self._d = int(dim)
        self._weights = weights if weights is not None else CostWeights({DEFAULT_TERM: 1.0})
        if not isinstance(self._weights, CostWeights):
            raise InvalidInputError("weights must be a CostWeights")
        self._n = 0
        self._X = np.zeros((16, self._d))
        self._T = np.zeros((16, len(self._weights)))
        self._c = np.zeros(16)

    def __len__(self) -> int:
        return self._n

    @property
    def dim(self) -> int:
        return self._d

    @property
    def weights(self) -> CostWeights:
        return self._weights

    @staticmethod
    def _ro(a: np.ndarray) -> np.ndarray:
        v = a.view()
        v.flags.writeable = False
        return v

    @property
    def points(self) -> np.ndarray:
        """(N, d), read-only view."""
        return self._ro(self._X[: self._n])

    @property
    def costs(self) -> np.ndarray:
        """(N,), read-only view, under the current weights."""
        return self._ro(self._c[: self._n])

    @property
    def terms(self) -> np.ndarray:
        """(N, K), columns in `weights.names` order, read-only view."""
        return self._ro(self._T[: self._n])

    def check_point(self, x: object) -> np.ndarray:
        xa = np.asarray(x, dtype=float)
        if xa.shape != (self._d,):
            raise InvalidInputError(f"parameters must have shape ({self._d},), got {xa.shape}")
        if not np.all(np.isfinite(xa)):
            raise InvalidInputError("parameters must be finite")
        return xa

    def prepare(self, x: object, terms: Mapping[str, float] | float) -> tuple[np.ndarray, np.ndarray, float]:
        """Validate without storing: (x (d,), term vector (K,), cost)."""
        xa = self.check_point(x)
        tv = self._weights.term_vector(terms)
        return xa, tv, float(self._weights.combine_rows(tv[None, :])[0])

    def add(self, x: object, terms: Mapping[str, float] | float) -> int:
        """Store one observation; returns its index.  Validates before changing anything."""
        xa, tv, cost = self.prepare(x, terms)
        if self._n == self._X.shape[0]:
            cap = 2 * self._X.shape[0]
            self._X = np.resize(self._X, (cap, self._d))
            self._T = np.resize(self._T, (cap, self._T.shape[1]))
            self._c = np.resize(self._c, cap)
        self._X[self._n] = xa
        self._T[self._n] = tv
        self._c[self._n] = cost
        self._n += 1
        return self._n - 1

    def truncate(self, n: int) -> None:
        """Drop observations n, n+1, ... (rollback of a failed tell)."""
        if not 0 <= n <= self._n:
            raise InvalidInputError(f"cannot truncate {self._n} observations to {n}")
        self._n = n

    def reweight(self, weights: CostWeights) -> None:
        """Recompute every stored cost under `weights` (same term names required)."""
        if not isinstance(weights, CostWeights):
            raise InvalidInputError("weights must be a CostWeights")
        unknown = sorted(set(weights.names) - set(self._weights.names))
        missing = sorted(set(self._weights.names) - set(weights.names))
        if unknown:
            raise UnknownTermError(f"weights for terms the observations do not have: {unknown}")
        if missing:
            raise MissingTermError(f"no weight for stored cost terms {missing}")
        self._weights = weights
        self._c[: self._n] = weights.combine_rows(self._T[: self._n])
