"""Exception types of the learner.  Every one is raised before any state changes."""

from __future__ import annotations


class LearnerError(Exception):
    """Base class of every error raised by ersac_hil.learner."""


class InvalidInputError(LearnerError, ValueError):
    """Wrong shape, non-finite value, bad configuration value."""


class OutOfBoundsError(InvalidInputError):
    """Parameters outside the configured bounds."""


class InvalidCostError(InvalidInputError):
    """A cost (or cost term) that is NaN/inf or not a number."""


class InvalidKappaError(InvalidInputError):
    """kappa must be a finite real number."""


class CostTermError(InvalidInputError):
    """Cost terms and weights do not match (base of Unknown/MissingTermError)."""


class UnknownTermError(CostTermError):
    """A cost term or weight name the learner does not know."""


class MissingTermError(CostTermError):
    """A cost term or weight the learner needs is absent."""


class ProtocolError(LearnerError, RuntimeError):
    """Calls in the wrong order (tell without ask)."""


class NoPendingAskError(ProtocolError):
    """tell() without a pending ask()."""


class PendingAskError(ProtocolError):
    """An operation that needs no pending ask() (setting theta) while one is pending."""


class PendingMismatchError(ProtocolError):
    """tell() with parameters other than the pending ask()'s."""


class StateError(LearnerError, ValueError):
    """A state dict that cannot be restored, or a resume that is incomplete."""


class InsufficientDataError(LearnerError, RuntimeError):
    """The critic or selection needs more observations than the learner has."""
