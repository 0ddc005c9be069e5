"""Noise models: how a sub-sensor's reading scatters around its expected value.

Every estimator of the package (likelihood, Fisher information and CRLB, ML,
posterior, evidence) sees the noise through one small interface, given the
expected readings ``mu`` (..., N) of a scene (Eq. 1, after gains, background and
offsets; :mod:`olsbayes.measurement`):

* ``log_likelihood(mu, data)`` and ``pointwise(mu, data)`` (per sub-sensor);
* ``score(mu, data)`` -- ``d log L / d mu`` and the Fisher weights ``w`` with
  ``F = J^T diag(w) J`` for the Jacobian ``J = d mu / d params``;
* ``simulate(mu, gen, shape)``;
* ``check_data(data)`` -- the readings this model accepts.

The records:

* :class:`GaussianKnown` (sigma): additive N(0, sigma^2), sigma known -- the
  package's default, w = 1 / sigma^2;
* :class:`GaussianUnknown` (sigma): the same noise, but sigma is inferred (ML
  profiles it out, the posterior gives it a prior); ``sigma`` is its true value
  for simulations and bounds, and the scale of its default prior;
* :class:`GaussianPerSensor` (sigma vector (N,)): w_n = 1 / sigma_n^2;
* :class:`Poisson` (exposure, dark): counts with mean ``exposure * (mu + dark)``,
  ``mu`` a rate; w_n = exposure / (mu_n + dark_n), the exact Poisson Fisher
  information ``sum (d lambda / d theta)^2 / lambda`` of the counts lambda.

Repeated frames: with ``frames=True`` the data carry a frame axis, (..., F, N),
every frame a reading of the same scene; log-likelihoods and scores sum over it.
A Poisson ``exposure`` may then be a vector (F,), one exposure per frame.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .base import MAX_COUNT, NoiseModel, frames_count
from .gaussian import GaussianKnown, GaussianPerSensor, GaussianUnknown
from .poisson import Poisson

__all__ = ["NoiseModel", "GaussianKnown", "GaussianUnknown", "GaussianPerSensor", "Poisson",
           "NOISE_KINDS", "noise_from_name", "MAX_COUNT", "frames_count"]


NOISE_KINDS = ("gaussian", "gaussian_unknown", "gaussian_per_sensor", "poisson")


def noise_from_name(kind: str, *, sigma: float | np.ndarray | None = None,
                    exposure: float | np.ndarray = 1.0,
                    dark: float | np.ndarray = 0.0) -> NoiseModel:
    """The noise model called ``kind`` (one of :data:`NOISE_KINDS`) with its settings."""
    key = str(kind).lower().replace("-", "_")
    if key not in NOISE_KINDS:
        raise InputError(f"noise model must be one of {', '.join(NOISE_KINDS)}; got {kind!r}")
    if key == "poisson":
        return Poisson(exposure, dark)
    if sigma is None:
        raise InputError(f"noise model {kind!r} needs sigma")
    if key == "gaussian_per_sensor":
        return GaussianPerSensor(sigma)
    if np.ndim(sigma):
        raise InputError(f"sigma of noise model {kind!r} must be one number; a vector "
                         "needs model = 'gaussian_per_sensor'")
    return GaussianKnown(float(sigma)) if key == "gaussian" else GaussianUnknown(float(sigma))
