"""ERSAC learner core: ask/tell learner, cost weighting, offline policy selection.

Pure numerics: no I/O, threads or sockets (the daemon shell lives elsewhere).
"""

from .costs import CostWeights, Observations
from .errors import (
    CostTermError,
    InsufficientDataError,
    InvalidCostError,
    InvalidInputError,
    InvalidKappaError,
    LearnerError,
    MissingTermError,
    NoPendingAskError,
    PendingAskError,
    OutOfBoundsError,
    PendingMismatchError,
    ProtocolError,
    StateError,
    UnknownTermError,
)
from .ersac import ERSAC, Update
from .selection import Selection, SelectionConfig, select_policy

__all__ = [
    "ERSAC",
    "CostTermError",
    "CostWeights",
    "InsufficientDataError",
    "InvalidCostError",
    "InvalidInputError",
    "InvalidKappaError",
    "LearnerError",
    "MissingTermError",
    "NoPendingAskError",
    "PendingAskError",
    "Observations",
    "OutOfBoundsError",
    "PendingMismatchError",
    "ProtocolError",
    "Selection",
    "SelectionConfig",
    "StateError",
    "UnknownTermError",
    "Update",
    "select_policy",
]
