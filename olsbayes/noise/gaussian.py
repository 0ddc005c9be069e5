"""Gaussian noise: one known sigma, one unknown sigma, a sigma per sub-sensor."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._validation import SIGMA_RANGE, finite_array, noise_sd
from ..errors import InputError
from .base import _LOG_2PI, NoiseModel, _expand, _frames_of, _sum_frames

__all__ = ["GaussianKnown", "GaussianUnknown", "GaussianPerSensor"]


@dataclass(frozen=True)
class GaussianKnown(NoiseModel):
    """Additive Gaussian noise of known sd ``sigma`` (reading units): the default."""

    sigma: float
    kind: ClassVar[str] = "gaussian"

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", noise_sd("sigma", self.sigma))

    @property
    def scale(self) -> float:
        """The noise sd sigma."""
        return self.sigma

    @property
    def is_default(self) -> bool:
        """Always True: the package's default noise."""
        return True

    def log_norm(self, n_sensors: int) -> float:
        """N (log sigma + log(2 pi) / 2): minus the log normalisation of one data vector."""
        return n_sensors * (np.log(self.sigma) + 0.5 * np.log(2 * np.pi))

    def pointwise(self, mu, data, *, frames=False, theta=None):
        """Log density per sub-sensor, summed over frames."""
        r = (data - _expand(mu, frames)) / self.sigma
        return _sum_frames(-0.5 * r * r - math.log(self.sigma) - 0.5 * _LOG_2PI, frames)

    def score(self, mu, data, *, frames=False, theta=None):
        """Residual / sigma^2 (summed over frames) and F / sigma^2."""
        n_f = _frames_of(data, frames)
        u = _sum_frames(data - _expand(mu, frames), frames) / self.sigma**2
        return u, np.full(u.shape, n_f / self.sigma**2)

    def weights(self, mu, *, n_frames=1, theta=None):
        """n_frames / sigma^2 for every sub-sensor."""
        return np.full(np.shape(mu), n_frames / self.sigma**2)

    def simulate(self, mu, gen, shape, n_frames=None):
        """``mu + sigma * z`` with z standard normal."""
        full = shape + (() if n_frames is None else (n_frames,)) + mu.shape
        return mu + self.sigma * gen.standard_normal(full)


@dataclass(frozen=True)
class GaussianUnknown(NoiseModel):
    """Additive Gaussian noise of one sd ``sigma`` that the estimators infer.

    ``sigma`` is the true value (simulations, Fisher bounds) and the scale of the
    default prior ``LogUniform(sigma / 100, 100 sigma)``; ML profiles it out
    (sigma^2 = RSS / (F N)).
    """

    sigma: float = 1.0
    kind: ClassVar[str] = "gaussian_unknown"
    inferred: ClassVar[tuple[str, ...]] = ("sigma",)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", noise_sd("sigma", self.sigma))

    @property
    def scale(self) -> float:
        """The nominal noise sd."""
        return self.sigma

    def nominal(self) -> np.ndarray:
        """``[sigma]``."""
        return np.array([self.sigma])

    def _sd(self, theta: np.ndarray | None) -> np.ndarray | float:
        return self.sigma if theta is None else np.asarray(theta, float)[..., 0:1]

    def pointwise(self, mu, data, *, frames=False, theta=None):
        """Log density per sub-sensor at sd ``theta[..., 0]``, summed over frames."""
        sd = self._sd(theta)
        sdf = sd[..., None, :] if frames and np.ndim(sd) else sd
        with np.errstate(divide="ignore", invalid="ignore"):
            r = (data - _expand(mu, frames)) / sdf
            return _sum_frames(-0.5 * r * r - np.log(sdf) - 0.5 * _LOG_2PI, frames)

    def score(self, mu, data, *, frames=False, theta=None):
        """Residual / sigma^2 and F / sigma^2 at sd ``theta[..., 0]``."""
        sd = self._sd(theta)
        n_f = _frames_of(data, frames)
        u = _sum_frames(data - _expand(mu, frames), frames) / sd**2
        return u, np.broadcast_to(n_f / sd**2, u.shape).copy()

    def weights(self, mu, *, n_frames=1, theta=None):
        """n_frames / sigma^2 for every sub-sensor."""
        return np.broadcast_to(n_frames / self._sd(theta) ** 2, np.shape(mu)).copy()

    def theta_information(self, mu, *, n_frames=1, theta=None):
        """2 F N / sigma^2: the information on sigma from F N Gaussian readings."""
        sd = np.broadcast_to(self._sd(theta), np.shape(mu)[:-1] + (1,))
        return (2.0 * n_frames * np.shape(mu)[-1] / sd**2)[..., None]

    def simulate(self, mu, gen, shape, n_frames=None):
        """``mu + sigma * z`` with z standard normal."""
        full = shape + (() if n_frames is None else (n_frames,)) + mu.shape
        return mu + self.sigma * gen.standard_normal(full)


@dataclass(frozen=True)
class GaussianPerSensor(NoiseModel):
    """Additive Gaussian noise with a known sd per sub-sensor, ``sigma`` (N,).

    E.g. measured from dark frames.  Every entry within
    :data:`~olsbayes._validation.SIGMA_RANGE`.
    """

    sigma: np.ndarray
    kind: ClassVar[str] = "gaussian_per_sensor"

    def __post_init__(self) -> None:
        arr = finite_array("sigma", self.sigma, ndim=1)
        lo, hi = SIGMA_RANGE
        if np.any(arr < lo) or np.any(arr > hi):
            bad = float(arr[(arr < lo) | (arr > hi)][0])
            raise InputError(f"sigma must hold sds in [{lo:g}, {hi:g}] (one per sub-sensor, "
                             f"no zeros); got {bad!r}")
        arr = arr.copy()
        arr.flags.writeable = False
        object.__setattr__(self, "sigma", arr)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, GaussianPerSensor) and np.array_equal(self.sigma, other.sigma)

    __hash__ = None  # type: ignore[assignment]

    @property
    def scale(self) -> float:
        """The root mean square of the sds."""
        return float(np.sqrt(np.mean(self.sigma**2)))

    def validate(self, n_sensors):
        """The sd vector must hold one entry per sub-sensor."""
        if self.sigma.shape != (n_sensors,):
            raise InputError(f"sigma must hold one sd per sub-sensor, shape ({n_sensors},); "
                             f"got shape {self.sigma.shape}")

    def pointwise(self, mu, data, *, frames=False, theta=None):
        """Log density per sub-sensor, summed over frames."""
        r = (data - _expand(mu, frames)) / self.sigma
        return _sum_frames(-0.5 * r * r - np.log(self.sigma) - 0.5 * _LOG_2PI, frames)

    def score(self, mu, data, *, frames=False, theta=None):
        """Residual / sigma_n^2 and F / sigma_n^2."""
        n_f = _frames_of(data, frames)
        u = _sum_frames(data - _expand(mu, frames), frames) / self.sigma**2
        return u, np.broadcast_to(n_f / self.sigma**2, u.shape).copy()

    def weights(self, mu, *, n_frames=1, theta=None):
        """n_frames / sigma_n^2."""
        return np.broadcast_to(n_frames / self.sigma**2, np.shape(mu)).copy()

    def simulate(self, mu, gen, shape, n_frames=None):
        """``mu + sigma_n * z`` with z standard normal."""
        full = shape + (() if n_frames is None else (n_frames,)) + mu.shape
        return mu + self.sigma * gen.standard_normal(full)

    def __repr__(self) -> str:
        return f"GaussianPerSensor(sigma=<{self.sigma.size} sds, rms {self.scale:.4g}>)"


