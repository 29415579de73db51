"""Exception types of the critic (GP, VHGP, local critic)."""

from __future__ import annotations


class CriticError(Exception):
    """Base class of every error raised by ersac_hil.critic."""


class CriticInputError(CriticError, ValueError):
    """Input arrays of the wrong shape, non-finite values, too few points."""


class NotFittedError(CriticError, RuntimeError):
    """predict()/bound() called before fit()."""


class FitError(CriticError, RuntimeError):
    """The optimiser could not find any numerically valid parameter set."""
