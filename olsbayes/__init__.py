"""olsbayes: Bayesian analysis of optics-less smart (OLS) radiation sensors.

Eq. 1 of Caulfield, Yaroslavsky et al. -- ``s[n] = sum_k I[k] costn(theta[k] -
theta_sensor[n]) + noise`` -- for rings, spheres, plates and any measured array;
maximum-likelihood fits, posteriors, evidence for the number of sources, imaging
and Monte Carlo studies, all judged against the Cramér–Rao lower bound.
"""

from ._version import __version__
from .bounds import CRLBResult, crlb, crlb_eq3, crlb_eq4
from .calibration import Calibration, calibrate
from .circular import wrap_angle
from .errors import (
    AntipodalWarning,
    ConfigError,
    ConvergenceWarning,
    EvidenceWarning,
    InputError,
    KinkWarning,
    MultimodalWarning,
    NearResolutionWarning,
    NullSpaceWarning,
    OlsBayesError,
    OlsBayesWarning,
    PriorBoundWarning,
    ResolutionWarning,
)
from .geometry import Plate, Ring, SensorArray, Sphere
from .imaging import ImageOptions, ImageResult, image
from .ml import FastOptions, MLResult, MultistartOptions, fit_ml
from .model import Model
from .noise import GaussianKnown, GaussianPerSensor, GaussianUnknown, NoiseModel, Poisson
from .nuisance import Nuisance
from .posterior import PosteriorResult, SamplerOptions, write_report
from .posterior import sample as sample_posterior
from .priors import ScenePrior, default_priors
from .scene import Scene
from .select import SelectionResult, SelectOptions, select_k
from .sensitivity import Cosine, CosinePower, CustomSensitivity, Sensitivity, get_sensitivity
from .studies import Estimator, run_study

__all__ = [
    "__version__",
    # geometry and sensitivity
    "SensorArray",
    "Ring",
    "Sphere",
    "Plate",
    "wrap_angle",
    "Sensitivity",
    "Cosine",
    "CosinePower",
    "CustomSensitivity",
    "get_sensitivity",
    # model
    "Scene",
    "Model",
    "NoiseModel",
    "GaussianKnown",
    "GaussianUnknown",
    "GaussianPerSensor",
    "Poisson",
    "Nuisance",
    "Calibration",
    "calibrate",
    "CRLBResult",
    "crlb",
    "crlb_eq3",
    "crlb_eq4",
    # maximum likelihood
    "fit_ml",
    "FastOptions",
    "MultistartOptions",
    "MLResult",
    # priors and posteriors
    "ScenePrior",
    "default_priors",
    "sample_posterior",
    "SamplerOptions",
    "PosteriorResult",
    "write_report",
    # imaging of known directions
    "image",
    "ImageOptions",
    "ImageResult",
    # studies
    "run_study",
    "Estimator",
    # number of sources
    "select_k",
    "SelectOptions",
    "SelectionResult",
    # errors and warnings
    "OlsBayesError",
    "InputError",
    "ConfigError",
    "OlsBayesWarning",
    "ResolutionWarning",
    "NearResolutionWarning",
    "KinkWarning",
    "ConvergenceWarning",
    "EvidenceWarning",
    "NullSpaceWarning",
    "MultimodalWarning",
    "AntipodalWarning",
    "PriorBoundWarning",
]
