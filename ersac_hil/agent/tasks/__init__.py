"""The tasks the agent serves, one module each, looked up by name.

    task = lookup(tasks, "bracing")     # UnknownTask (reply ``unknown_task``) if not served

``default_tasks()`` is every task of this package with its default configuration (for the
limits of one robot description: ``default_tasks(RobotParameters.from_description(d))``); an agent may
serve a subset (``EpisodeConfig.tasks``). A task name is also a key of the contract's
``protocol.zenoh.TASKS`` (parameter box, cost-term names, horizon).
"""
from __future__ import annotations

from collections.abc import Mapping

from ersac_hil.agent.robot import UBOT, RobotParameters

from ersac_hil.agent.tasks.base import Balance, EmcyMark, EndCondition, Task, UnknownTask
from ersac_hil.agent.tasks.bracing import BracingSetup, BracingTask
from ersac_hil.agent.tasks.lifting import LiftingSetup, LiftingTask

__all__ = ["Balance", "BracingSetup", "BracingTask", "EmcyMark", "EndCondition", "LiftingSetup", "LiftingTask",
           "Task", "UnknownTask", "default_tasks", "lookup"]

_TASK_TYPES: tuple[type[Task], ...] = (BracingTask, LiftingTask)


def default_tasks(robot: RobotParameters = UBOT) -> dict[str, Task]:
    """Every task with its default configuration for ``robot``'s limits, by name."""
    return {cls.name: cls() if robot == UBOT else cls.for_robot(robot) for cls in _TASK_TYPES}


def lookup(tasks: Mapping[str, Task], name: str) -> Task:
    """The task called ``name``; ``UnknownTask`` if it is not among ``tasks``."""
    try:
        return tasks[name]
    except KeyError:
        raise UnknownTask(f"task {name!r} is not served by this agent; it serves "
                          f"{sorted(tasks)}") from None
