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

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.special import gammaln, xlogy

from ._validation import SIGMA_RANGE, finite_array, integer, noise_sd, real_array
from .errors import InputError

__all__ = ["NoiseModel", "GaussianKnown", "GaussianUnknown", "GaussianPerSensor", "Poisson",
           "NOISE_KINDS", "noise_from_name", "MAX_COUNT"]

_LOG_2PI = math.log(2.0 * math.pi)
#: Largest count a Poisson reading may hold (float64 represents integers exactly below 2^53).
MAX_COUNT = 2.0**53
#: Smallest expected count used in a logarithm: a count where the model expects none
#: costs a large but finite penalty, so an optimiser can leave such a point.
_TINY = 1e-300


def _frames_of(data: np.ndarray, frames: bool) -> int:
    """Number of frames F of ``data`` (1 without a frame axis)."""
    return int(data.shape[-2]) if frames else 1


def _sum_frames(values: np.ndarray, frames: bool) -> np.ndarray:
    """Sum over the frame axis (-2) when there is one."""
    return values.sum(axis=-2) if frames else values


def _expand(mu: np.ndarray, frames: bool) -> np.ndarray:
    """``mu`` (..., N) broadcast against data with a frame axis (..., F, N)."""
    return mu[..., None, :] if frames else mu


class NoiseModel(ABC):
    """Base of the noise models (see the module docstring).

    ``theta`` arguments are the values (..., Q) of the noise parameters that are
    inferred (:attr:`inferred`; Q = 0 for the models without any), None meaning
    their nominal values (:meth:`nominal`).
    """

    #: Configuration name (``[noise] model``).
    kind: ClassVar[str] = ""
    #: Names of the noise parameters an estimator infers.
    inferred: ClassVar[tuple[str, ...]] = ()

    @property
    @abstractmethod
    def scale(self) -> float:
        """A nominal sd of one reading (reading units): unit checks and default priors."""

    @property
    def is_default(self) -> bool:
        """True for Gaussian noise of one known sigma (the package's default path)."""
        return False

    def nominal(self) -> np.ndarray:
        """Nominal (true) values (Q,) of the inferred noise parameters."""
        return np.zeros(0)

    def validate(self, n_sensors: int) -> None:
        """Refuse parameter vectors that do not fit an array of ``n_sensors``."""

    def check_data(self, data: object, n_sensors: int, *, frames: bool = False,
                   name: str = "data") -> np.ndarray:
        """Readings as a float array (..., N) or with frames (..., F, N), checked."""
        arr = finite_array(name, data, last=n_sensors)
        if frames and arr.ndim < 2:
            raise InputError(f"{name} with frames must have shape (..., F, {n_sensors}) "
                             f"(F frames of {n_sensors} readings); got shape {arr.shape}")
        return arr

    @abstractmethod
    def pointwise(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
                  theta: np.ndarray | None = None) -> np.ndarray:
        """Log density per sub-sensor (..., N), summed over frames."""

    def log_likelihood(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
                       theta: np.ndarray | None = None) -> np.ndarray:
        """Total log-likelihood (...,) of ``data`` given expected readings ``mu`` (..., N)."""
        return np.sum(self.pointwise(mu, data, frames=frames, theta=theta), axis=-1)

    @abstractmethod
    def score(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
              theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(d log L / d mu, w)``, each (..., N): gradient and Fisher weights at ``mu``."""

    @abstractmethod
    def weights(self, mu: np.ndarray, *, n_frames: int = 1,
                theta: np.ndarray | None = None) -> np.ndarray:
        """Fisher weights w (..., N): ``F = J^T diag(w) J`` for ``n_frames`` frames."""

    def theta_information(self, mu: np.ndarray, *, n_frames: int = 1,
                          theta: np.ndarray | None = None) -> np.ndarray:
        """Fisher information (..., Q, Q) of the inferred noise parameters.

        Their cross information with the mean parameters is zero for every model here.
        """
        return np.zeros(np.shape(mu)[:-1] + (0, 0))

    @abstractmethod
    def simulate(self, mu: np.ndarray, gen: np.random.Generator, shape: tuple[int, ...],
                 n_frames: int | None = None) -> np.ndarray:
        """Noisy readings ``shape + mu.shape`` (frames: ``shape + (F,) + mu.shape``)."""

    def describe(self) -> str:
        """One line naming the model and its settings."""
        return repr(self)


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


@dataclass(frozen=True)
class Poisson(NoiseModel):
    """Counting noise: readings are counts ~ Poisson(exposure * (mu + dark)).

    Parameters
    ----------
    exposure : float or ndarray (F,)
        Exposure time (> 0) converting the rate ``mu + dark`` into expected counts;
        a vector gives one exposure per frame (data with frames of that length).
    dark : float or ndarray (N,)
        Known dark rate (>= 0) of every sub-sensor, in the units of ``mu``.
    """

    exposure: float | np.ndarray = 1.0
    dark: float | np.ndarray = 0.0
    kind: ClassVar[str] = "poisson"

    def __post_init__(self) -> None:
        e = finite_array("exposure", self.exposure, ndim=(0, 1))
        if np.any(e <= 0):
            raise InputError(f"exposure must be > 0 (a time); got minimum {float(e.min())!r}")
        d = finite_array("dark", self.dark, ndim=(0, 1), nonnegative=True)
        for name, arr in (("exposure", e), ("dark", d)):
            value = float(arr) if arr.ndim == 0 else arr.copy()
            if arr.ndim:
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Poisson) and np.array_equal(self.exposure, other.exposure)
                and np.array_equal(self.dark, other.dark))

    __hash__ = None  # type: ignore[assignment]

    @property
    def scale(self) -> float:
        """One count, in rate units: 1 / mean exposure."""
        return float(1.0 / np.mean(self.exposure))

    @property
    def n_frames(self) -> int | None:
        """Frames the exposure vector describes (None for one scalar exposure)."""
        return None if np.ndim(self.exposure) == 0 else int(np.size(self.exposure))

    def total_exposure(self, n_frames: int = 1) -> float:
        """Sum of the exposures of ``n_frames`` frames (the vector's sum when given)."""
        return float(np.sum(self.exposure)) if np.ndim(self.exposure) else (
            n_frames * float(self.exposure))

    def validate(self, n_sensors):
        """A dark vector must hold one rate per sub-sensor."""
        if np.ndim(self.dark) and np.shape(self.dark) != (n_sensors,):
            raise InputError(f"dark must be a number or one rate per sub-sensor, shape "
                             f"({n_sensors},); got shape {np.shape(self.dark)}")

    def check_data(self, data, n_sensors, *, frames=False, name="data"):
        """Counts: non-negative integers below 2^53, frames matching the exposures."""
        arr = real_array(name, data)
        if arr.ndim == 0 or arr.shape[-1] != n_sensors:
            raise InputError(f"{name} must have last axis of length {n_sensors}; got shape "
                             f"{arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be finite counts (no NaN or inf)")
        if np.any(arr < 0) or np.any(arr != np.round(arr)) or np.any(arr > MAX_COUNT):
            raise InputError(f"{name} under Poisson noise must hold counts: integers in "
                             f"[0, 2^53]; got {self._worst(arr)}")
        if frames and arr.ndim < 2:
            raise InputError(f"{name} with frames must have shape (..., F, {n_sensors}); "
                             f"got shape {arr.shape}")
        f = self.n_frames
        if f is not None and (not frames or arr.shape[-2] != f):
            raise InputError(f"{name} must hold {f} frames (one per exposure), shape "
                             f"(..., {f}, {n_sensors}) with frames=True; got shape {arr.shape}")
        return arr

    @staticmethod
    def _worst(arr: np.ndarray) -> str:
        bad = arr[(arr < 0) | (arr != np.round(arr)) | (arr > MAX_COUNT)]
        return f"{float(bad[0])!r}"

    def _lam(self, mu: np.ndarray, frames: bool) -> np.ndarray:
        """Expected counts: exposure * (mu + dark), per frame with frames."""
        rate = mu + self.dark
        if not frames:
            return self.exposure * rate
        e = np.asarray(self.exposure, float)
        return (e[:, None] if e.ndim else e) * rate[..., None, :]

    def pointwise(self, mu, data, *, frames=False, theta=None):
        """``s log lambda - lambda - log s!`` per sub-sensor, summed over frames."""
        lam = self._lam(np.asarray(mu, float), frames)
        with np.errstate(divide="ignore"):
            term = xlogy(data, np.maximum(lam, _TINY)) - lam - gammaln(data + 1.0)
        return _sum_frames(term, frames)

    def score(self, mu, data, *, frames=False, theta=None):
        """``S / (mu + dark) - E`` and ``E / (mu + dark)``: S the counts summed over frames."""
        rate = np.maximum(np.asarray(mu, float) + self.dark, _TINY)
        counts = _sum_frames(data, frames)
        e_tot = self.total_exposure(_frames_of(data, frames))
        return counts / rate - e_tot, e_tot / rate

    def weights(self, mu, *, n_frames=1, theta=None):
        """E / (mu + dark), with E the total exposure: the Poisson Fisher weights."""
        rate = np.maximum(np.asarray(mu, float) + self.dark, _TINY)
        return self.total_exposure(n_frames) / rate

    def simulate(self, mu, gen, shape, n_frames=None):
        """Poisson counts of mean exposure * (mu + dark); one frame per exposure entry."""
        if n_frames is None and self.n_frames is not None:
            n_frames = self.n_frames
        lam = self._lam(np.asarray(mu, float), n_frames is not None)
        if n_frames is not None and self.n_frames is None:
            lam = np.repeat(lam, n_frames, axis=-2)
        if np.any(lam < 0):
            raise InputError("Poisson simulation needs expected counts >= 0 (a negative "
                             "offset or rate?)")
        return gen.poisson(np.broadcast_to(lam, shape + lam.shape)).astype(float)

    def __repr__(self) -> str:
        def short(v):
            return f"{v!r}" if np.ndim(v) == 0 else f"<{np.size(v)} values>"
        return f"Poisson(exposure={short(self.exposure)}, dark={short(self.dark)})"


#: Configuration names of the noise models.
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


def frames_count(data: np.ndarray, frames: bool) -> int:
    """Number of frames of ``data`` (1 without frames); checked >= 1."""
    return integer("number of frames", _frames_of(data, frames), low=1)
