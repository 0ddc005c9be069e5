"""olsbayes: Bayesian analysis of optics-less smart (OLS) radiation sensors.

Eq. 1 of Caulfield, Yaroslavsky et al. -- ``s[n] = sum_k I[k] costn(theta[k] -
theta_sensor[n]) + noise`` -- for rings, spheres, plates and any measured array;
maximum-likelihood fits, posteriors, evidence for the number of sources, imaging
and Monte Carlo studies, all judged against the Cramér–Rao lower bound.
"""

from importlib import import_module
from typing import TYPE_CHECKING

from ._version import __version__
from .bounds import CRLBResult, crlb, crlb_eq3, crlb_eq4
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
from .ml import FastOptions, MLResult, MultistartOptions, fit_ml
from .model import Model
from .noise import GaussianKnown, GaussianPerSensor, GaussianUnknown, NoiseModel, Poisson
from .nuisance import Nuisance
from .priors import ScenePrior, default_priors
from .scene import Scene
from .sensitivity import Cosine, CosinePower, CustomSensitivity, Sensitivity, get_sensitivity

if TYPE_CHECKING:  # the names below are served lazily at run time (__getattr__)
    from .calibration import Calibration, calibrate
    from .imaging import ImageOptions, ImageResult, image
    from .posterior import PosteriorResult, SamplerOptions, write_report
    from .posterior import sample as sample_posterior
    from .select import SelectionResult, SelectOptions, select_k
    from .studies import Estimator, run_study

#: Names of the package's wings that load on first use: (module, attribute).  A fit
#: or a study worker then imports neither the samplers, the imaging nor the model
#: selection (each 10-50 ms of a new process's start); ``ob.image`` and
#: ``ob.imaging.image`` import them when first touched.
_LAZY = {
    "Calibration": ("calibration", "Calibration"),
    "calibrate": ("calibration", "calibrate"),
    "image": ("imaging", "image"),
    "ImageOptions": ("imaging", "ImageOptions"),
    "ImageResult": ("imaging", "ImageResult"),
    "PosteriorResult": ("posterior", "PosteriorResult"),
    "SamplerOptions": ("posterior", "SamplerOptions"),
    "write_report": ("posterior", "write_report"),
    "sample_posterior": ("posterior", "sample"),
    "SelectionResult": ("select", "SelectionResult"),
    "SelectOptions": ("select", "SelectOptions"),
    "select_k": ("select", "select_k"),
    "Estimator": ("studies", "Estimator"),
    "run_study": ("studies", "run_study"),
}

#: Submodules reachable as attributes of the package before they are imported.
_SUBMODULES = frozenset({"calibration", "cli", "config", "imaging", "ml", "noise",
                          "plotting", "posterior", "priors", "select", "studies"})


def __getattr__(name: str) -> object:
    """A lazily served name (:data:`_LAZY`) or submodule, imported on first access."""
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(import_module(f".{module}", __name__), attr)
    elif name in _SUBMODULES:
        value = import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__) | _SUBMODULES)


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
