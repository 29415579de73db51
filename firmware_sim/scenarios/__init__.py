"""Scenarios (tasks): the props, initial state, test-bench actions and ground truth of an episode."""
from .base import Scenario, balanced_qpos
from .bracing import Bracing
from .lifting import Lifting

SCENARIOS: dict[str, type[Scenario]] = {"idle": Scenario, "bracing": Bracing, "lifting": Lifting}
"""Scenario classes by name (the names match protocol.can.objects.Scenario)."""


class UnknownScenarioError(KeyError):
    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown scenario"


def make(name: str) -> Scenario:
    try:
        return SCENARIOS[name]()
    except KeyError:
        raise UnknownScenarioError(f"unknown scenario {name!r}; known: {sorted(SCENARIOS)}") from None


__all__ = ["SCENARIOS", "Scenario", "Bracing", "Lifting", "UnknownScenarioError", "balanced_qpos", "make"]
