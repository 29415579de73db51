"""The ERSAC critic: GP, variational heteroscedastic GP (VHGP) and the local critic.

Pure numerics (numpy/scipy): no I/O, threads or sockets.  BLAS is pinned to one thread
inside every fit/predict call (see _blas.py).
"""

from .bound import vhgp_bound
from .errors import CriticError, CriticInputError, FitError, NotFittedError
from .gp import GP, GPHyperparameters, GPPrediction
from .local import CriticConfig, CriticData, CriticEstimate, LocalCritic, LocalFit
from .prior import CriticPrior
from .vhgp import (
    VHGP,
    VHGPHyperparameters,
    VHGPParams,
    VHGPPrediction,
    VHGPPredictionGradient,
)

__all__ = [
    "GP",
    "VHGP",
    "CriticConfig",
    "CriticData",
    "CriticError",
    "CriticEstimate",
    "CriticInputError",
    "CriticPrior",
    "FitError",
    "GPHyperparameters",
    "GPPrediction",
    "LocalCritic",
    "LocalFit",
    "NotFittedError",
    "VHGPHyperparameters",
    "VHGPParams",
    "VHGPPrediction",
    "VHGPPredictionGradient",
    "vhgp_bound",
]
