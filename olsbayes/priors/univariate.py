"""One-dimensional priors with one small vectorised interface.

Every prior has a support ``[lower, upper]`` and

* ``log_prob(x)`` -- log density, ``-inf`` outside the support (any shape);
* ``cdf(x)`` and ``ppf(u)`` -- distribution function and its inverse, the
  latter mapping the unit interval onto the support (for unit-cube samplers
  such as dynesty);
* ``sample(size, rng)`` -- draws through an explicit generator (``ppf`` of
  uniforms, so a seed gives the same draws on every platform);
* ``periodic`` -- True for a coordinate on a circle, whose density is
  evaluated at the wrapped angle (``log_prob(x) == log_prob(x + 2 pi)``).

The classes are frozen dataclasses, so priors compare by value and can be
written into configuration files and result metadata.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, finite_array, positive_float
from ..circular import wrap_angle
from ..errors import InputError

__all__ = [
    "Prior",
    "Uniform",
    "LogUniform",
    "HalfNormal",
    "Exponential",
    "CircularUniform",
    "SinLatitude",
    "Normal",
    "LogNormal",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


def _finite_bound(name: str, value: object) -> float:
    arr = finite_array(name, value, ndim=0)
    return float(arr)


class Prior(ABC):
    """Base class of the 1-D priors (see the module docstring).

    Subclasses define ``lower``, ``upper``, ``_log_pdf(x)``, ``_cdf(x)`` and
    ``_ppf(u)`` on the inside of the support.
    """

    periodic: bool = False
    #: True when the density is constant on the support (Uniform, CircularUniform).
    flat: bool = False

    @property
    @abstractmethod
    def lower(self) -> float:
        """Lower end of the support."""

    @property
    @abstractmethod
    def upper(self) -> float:
        """Upper end of the support."""

    @property
    def support(self) -> tuple[float, float]:
        """``(lower, upper)`` of the support."""
        return (self.lower, self.upper)

    def _prepare(self, x: np.ndarray) -> np.ndarray:
        return wrap_angle(x) if self.periodic else x

    def log_prob(self, x: np.ndarray | float) -> np.ndarray:
        """Log density at ``x`` (any shape); ``-inf`` outside the support or at NaN."""
        x = self._prepare(np.asarray(x, dtype=float))
        inside = (x >= self.lower) & (x <= self.upper)
        out = np.full(x.shape, -np.inf)
        out[inside] = self._log_pdf(x[inside])
        return out if out.ndim else float(out)

    def prob(self, x: np.ndarray | float) -> np.ndarray:
        """Density at ``x``: ``exp(log_prob(x))``."""
        return np.exp(self.log_prob(x))

    def cdf(self, x: np.ndarray | float) -> np.ndarray:
        """P(X <= x); 0 below and 1 above the support (NaN stays NaN)."""
        x = self._prepare(np.asarray(x, dtype=float))
        inside = (x > self.lower) & (x < self.upper)
        out = np.where(x >= self.upper, 1.0, 0.0)
        out[np.isnan(x)] = np.nan
        out[inside] = self._cdf(x[inside])
        return out if out.ndim else float(out)

    def ppf(self, u: np.ndarray | float) -> np.ndarray:
        """Quantile function: ``u`` in [0, 1] onto the support; NaN outside [0, 1]."""
        u = np.asarray(u, dtype=float)
        ok = (u >= 0.0) & (u <= 1.0)
        out = np.full(u.shape, np.nan)
        out[ok] = self._ppf(u[ok])
        return out if out.ndim else float(out)

    def sample(
        self, size: int | tuple[int, ...] | None = None, *, rng: object = None
    ) -> np.ndarray:
        """Draws of shape ``size`` via ``ppf`` of uniforms from ``rng``."""
        gen = as_rng(rng)
        return self.ppf(gen.random(size))

    def to_scipy(self):  # noqa: ANN201 - scipy frozen distribution or None
        """The equivalent frozen ``scipy.stats`` distribution, or None."""
        return None

    # subclass hooks ------------------------------------------------------------
    @abstractmethod
    def _log_pdf(self, x: np.ndarray) -> np.ndarray:
        """log density inside the support."""

    @abstractmethod
    def _cdf(self, x: np.ndarray) -> np.ndarray:
        """CDF inside the support."""

    @abstractmethod
    def _ppf(self, u: np.ndarray) -> np.ndarray:
        """Inverse CDF for u in (0, 1)."""


@dataclass(frozen=True)
class Uniform(Prior):
    """Uniform on ``[lo, hi]`` (e.g. intensities ``Uniform(0, i_max)``, plate boxes)."""

    lo: float
    hi: float
    flat = True

    def __post_init__(self) -> None:
        lo, hi = _finite_bound("lo", self.lo), _finite_bound("hi", self.hi)
        if not hi > lo:
            raise InputError(f"Uniform needs lo < hi; got lo={lo!r}, hi={hi!r}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    lower = property(lambda self: self.lo)
    upper = property(lambda self: self.hi)

    def _log_pdf(self, x):
        return np.full(x.shape, -np.log(self.hi - self.lo))

    def _cdf(self, x):
        return (x - self.lo) / (self.hi - self.lo)

    def _ppf(self, u):
        return self.lo + u * (self.hi - self.lo)

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.uniform`` on ``[lo, hi]``."""
        from scipy import stats

        return stats.uniform(loc=self.lo, scale=self.hi - self.lo)


@dataclass(frozen=True)
class LogUniform(Prior):
    """Density proportional to 1/x on ``[lo, hi]``, 0 < lo < hi (scale parameters)."""

    lo: float
    hi: float

    def __post_init__(self) -> None:
        lo = positive_float("lo", self.lo)
        hi = positive_float("hi", self.hi)
        if not hi > lo:
            raise InputError(f"LogUniform needs 0 < lo < hi; got lo={lo!r}, hi={hi!r}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    lower = property(lambda self: self.lo)
    upper = property(lambda self: self.hi)

    @property
    def _log_ratio(self) -> float:
        return float(np.log(self.hi / self.lo))

    def _log_pdf(self, x):
        return -np.log(x) - np.log(self._log_ratio)

    def _cdf(self, x):
        return np.log(x / self.lo) / self._log_ratio

    def _ppf(self, u):
        return self.lo * np.exp(u * self._log_ratio)

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.loguniform(lo, hi)``."""
        from scipy import stats

        return stats.loguniform(self.lo, self.hi)


@dataclass(frozen=True)
class HalfNormal(Prior):
    """Half-normal on ``[0, inf)`` with scale ``scale`` (sd of the parent normal)."""

    scale: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale", positive_float("scale", self.scale))

    lower = property(lambda self: 0.0)
    upper = property(lambda self: np.inf)

    def _log_pdf(self, x):
        z = x / self.scale
        return 0.5 * np.log(2.0 / np.pi) - np.log(self.scale) - 0.5 * z * z

    def _cdf(self, x):
        from scipy.special import erf

        return erf(x / (self.scale * np.sqrt(2.0)))

    def _ppf(self, u):
        from scipy.special import erfinv

        return self.scale * np.sqrt(2.0) * erfinv(u)

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.halfnorm(scale=scale)``."""
        from scipy import stats

        return stats.halfnorm(scale=self.scale)


@dataclass(frozen=True)
class Exponential(Prior):
    """Exponential on ``[0, inf)`` with mean ``scale``."""

    scale: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale", positive_float("scale", self.scale))

    lower = property(lambda self: 0.0)
    upper = property(lambda self: np.inf)

    def _log_pdf(self, x):
        return -x / self.scale - np.log(self.scale)

    def _cdf(self, x):
        return -np.expm1(-x / self.scale)

    def _ppf(self, u):
        return -self.scale * np.log1p(-u)

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.expon(scale=scale)``."""
        from scipy import stats

        return stats.expon(scale=self.scale)


@dataclass(frozen=True)
class CircularUniform(Prior):
    """Uniform angle on the circle, support ``(-pi, pi]`` (rad), periodic.

    ``log_prob`` wraps its argument first, so it is ``-log(2 pi)`` for every
    finite angle; ``ppf`` maps [0, 1] onto [-pi, pi].  A ring source direction
    or a sphere longitude gets this prior; dynesty should treat it as periodic.
    """

    periodic = True
    flat = True

    lower = property(lambda self: -np.pi)
    upper = property(lambda self: np.pi)

    def _log_pdf(self, x):
        return np.full(x.shape, -_LOG_2PI)

    def _cdf(self, x):
        return (x + np.pi) / (2.0 * np.pi)

    def _ppf(self, u):
        return -np.pi + 2.0 * np.pi * u

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.uniform`` on ``[-pi, pi]``."""
        from scipy import stats

        return stats.uniform(loc=-np.pi, scale=2.0 * np.pi)


@dataclass(frozen=True)
class SinLatitude(Prior):
    """Isotropic latitude: density ``cos(lat) / 2`` on ``[-pi/2, pi/2]`` (rad).

    With a :class:`CircularUniform` longitude this is the uniform distribution
    on the sphere (``sin(lat)`` uniform on [-1, 1]).
    """

    lower = property(lambda self: -np.pi / 2)
    upper = property(lambda self: np.pi / 2)

    def _log_pdf(self, x):
        with np.errstate(divide="ignore"):
            return np.log(np.cos(x)) - np.log(2.0)

    def _cdf(self, x):
        return 0.5 * (1.0 + np.sin(x))

    def _ppf(self, u):
        return np.arcsin(np.clip(2.0 * u - 1.0, -1.0, 1.0))

    # no scipy.stats counterpart: sin(lat) ~ Uniform(-1, 1) is the check.


@dataclass(frozen=True)
class Normal(Prior):
    """Normal (Gaussian) with mean ``mean`` and sd ``sd`` on the real line.

    E.g. a sub-sensor's offset known from a calibration to within ``sd``.
    """

    mean: float
    sd: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", _finite_bound("mean", self.mean))
        object.__setattr__(self, "sd", positive_float("sd", self.sd))

    lower = property(lambda self: -np.inf)
    upper = property(lambda self: np.inf)

    def _log_pdf(self, x):
        z = (x - self.mean) / self.sd
        return -0.5 * z * z - np.log(self.sd) - 0.5 * _LOG_2PI

    def _cdf(self, x):
        from scipy.special import ndtr

        return ndtr((x - self.mean) / self.sd)

    def _ppf(self, u):
        from scipy.special import ndtri

        return self.mean + self.sd * ndtri(u)

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.norm(mean, sd)``."""
        from scipy import stats

        return stats.norm(loc=self.mean, scale=self.sd)


@dataclass(frozen=True)
class LogNormal(Prior):
    """log x ~ Normal(``mu``, ``s``) on (0, inf): a positive factor known to a relative ``s``.

    ``LogNormal(0, s)`` is a sub-sensor gain around 1 with relative sd about ``s``.
    """

    mu: float
    s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mu", _finite_bound("mu", self.mu))
        object.__setattr__(self, "s", positive_float("s", self.s))

    lower = property(lambda self: 0.0)
    upper = property(lambda self: np.inf)

    def _log_pdf(self, x):
        with np.errstate(divide="ignore", invalid="ignore"):
            lx = np.log(x)
            z = (lx - self.mu) / self.s
            return np.where(x > 0, -0.5 * z * z - lx - np.log(self.s) - 0.5 * _LOG_2PI,
                            -np.inf)

    def _cdf(self, x):
        from scipy.special import ndtr

        with np.errstate(divide="ignore"):
            return ndtr((np.log(x) - self.mu) / self.s)

    def _ppf(self, u):
        from scipy.special import ndtri

        return np.exp(self.mu + self.s * ndtri(u))

    def to_scipy(self):
        """The equivalent frozen ``scipy.stats.lognorm(s, scale=exp(mu))``."""
        from scipy import stats

        return stats.lognorm(self.s, scale=np.exp(self.mu))
