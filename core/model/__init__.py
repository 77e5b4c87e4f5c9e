"""The surrogate model: a heteroskedastic GP of the hardness map (exact, or interpolated on a grid for large designs).

Modules, one concern each: ``observations`` (what it learns from), ``kernels`` (kernel math, parameters,
gpytorch's model of record), ``exact`` and ``ski`` (the two GPs' likelihoods and conditioning),
``fitting`` (optimiser, warm and cold starts, refit schedule), ``noise`` (σ²(x) from the spreads),
``guard`` (length-scale collapse), ``hyper`` (typed hyperparameters and their journal codec) and
``surrogate`` (the model the campaign uses).
"""

from core.model.guard import GUARDS, GuardName
from core.model.hyper import Hyperparameters, ModelKind, NoiseKind
from core.model.kernels import KernelName
from core.model.observations import Observations
from core.model.ski import SKI_ABOVE
from core.model.surrogate import FitReport, HeteroskedasticGP, Prediction

__all__ = [
    "GUARDS",
    "SKI_ABOVE",
    "FitReport",
    "GuardName",
    "HeteroskedasticGP",
    "Hyperparameters",
    "KernelName",
    "ModelKind",
    "NoiseKind",
    "Observations",
    "Prediction",
]
