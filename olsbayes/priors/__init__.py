"""Priors: 1-D building blocks, the joint prior of a scene, and priors on K.

All 1-D priors share one vectorised interface (``log_prob``, ``cdf``, ``ppf``,
``sample``, ``support``, ``periodic``); :class:`ScenePrior` assembles them into
the joint prior of K exchangeable sources in the model's flat layout (see its
module docstring for the K! bookkeeping), and :class:`PoissonCount` /
:class:`UniformCount` weight the number of sources.
"""

from .counts import CountPrior, PoissonCount, UniformCount
from .defaults import data_intensity_bound, default_priors
from .scene import ScenePrior
from .univariate import (
    CircularUniform,
    Exponential,
    HalfNormal,
    LogNormal,
    LogUniform,
    Normal,
    Prior,
    SinLatitude,
    Uniform,
)

__all__ = [
    "Prior",
    "Uniform",
    "LogUniform",
    "Normal",
    "LogNormal",
    "HalfNormal",
    "Exponential",
    "CircularUniform",
    "SinLatitude",
    "ScenePrior",
    "default_priors",
    "data_intensity_bound",
    "CountPrior",
    "PoissonCount",
    "UniformCount",
]
