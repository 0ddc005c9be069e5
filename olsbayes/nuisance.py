"""Nuisance terms of a real array: per-sensor gains and offsets, a diffuse background.

The expected reading of sub-sensor n is

    mu_n = g_n (r_n + b) + o_n

with r_n the Eq. 1 response of the sources, g_n > 0 its gain, o_n its offset
(for Poisson counts: a dark rate added to the rate) and b >= 0 an isotropic
diffuse background: a uniform radiance seen through a sub-sensor's angular law
gives every sub-sensor the same reading b (in intensity units).

Each term is either **known** (a value) or **inferred** (a prior is given; the
value is then the truth used in simulations and the point at which bounds are
evaluated).  Inferred terms become extra parameters, in the order
``b``, ``g[0..N-1]``, ``o[0..N-1]`` (:meth:`Nuisance.names`), appended after the
scene's parameters and the noise model's own (``sigma`` when inferred).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import finite_array, nonnegative_float
from .errors import InputError
from .priors.univariate import Prior

__all__ = ["Nuisance", "prior_precision"]


def _vector_or_scalar(name: str, value: object, *, positive: bool = False) -> float | np.ndarray:
    arr = finite_array(name, value, ndim=(0, 1))
    if positive and np.any(arr <= 0):
        raise InputError(f"{name} must be > 0 (a gain multiplies the response); got minimum "
                         f"{float(arr.min())!r}")
    if arr.ndim == 0:
        return float(arr)
    arr = arr.copy()
    arr.flags.writeable = False
    return arr


def _priors(name: str, value: object, low: float) -> tuple[Prior, ...] | Prior | None:
    """None, one Prior shared by every sub-sensor, or a tuple of them (one each)."""
    if value is None or isinstance(value, Prior):
        items = () if value is None else (value,)
    elif isinstance(value, (tuple, list)) and all(isinstance(p, Prior) for p in value):
        items = tuple(value)
    else:
        raise InputError(f"{name} must be None, an olsbayes.priors prior or a sequence of "
                         f"them (one per sub-sensor); got {type(value).__name__}")
    for p in items:
        if p.lower < low or p.periodic:
            raise InputError(f"{name} {p!r} must have support within [{low:g}, inf)")
    return tuple(value) if isinstance(value, list) else value


@dataclass(frozen=True, eq=False)
class Nuisance:
    """Gains, offsets and background of an array: known values or priors to infer them.

    Parameters
    ----------
    gains : float or ndarray (N,)
        Sub-sensor gains (> 0); 1 by default.
    offsets : float or ndarray (N,)
        Sub-sensor offsets (reading units; Poisson: dark rates added to the rate).
    background : float
        Isotropic diffuse background (>= 0, intensity units).
    gain_prior, offset_prior : Prior or sequence of N Priors, optional
        Given: the gains (offsets) are inferred with this prior, e.g.
        ``LogNormal(0, 0.05)`` for gains known to about 5 %.  Gain priors must live
        on (0, inf).
    background_prior : Prior, optional
        Given: the background is inferred with this prior (support within [0, inf)).
    """

    gains: float | np.ndarray = 1.0
    offsets: float | np.ndarray = 0.0
    background: float = 0.0
    gain_prior: Prior | tuple[Prior, ...] | None = None
    offset_prior: Prior | tuple[Prior, ...] | None = None
    background_prior: Prior | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "gains", _vector_or_scalar("gains", self.gains, positive=True))
        object.__setattr__(self, "offsets", _vector_or_scalar("offsets", self.offsets))
        object.__setattr__(self, "background", nonnegative_float("background", self.background))
        object.__setattr__(self, "gain_prior", _priors("gain_prior", self.gain_prior, 0.0))
        object.__setattr__(self, "offset_prior",
                           _priors("offset_prior", self.offset_prior, -np.inf))
        if self.background_prior is not None and not isinstance(self.background_prior, Prior):
            raise InputError("background_prior must be None or an olsbayes.priors prior; got "
                             f"{type(self.background_prior).__name__}")
        _priors("background_prior", self.background_prior, 0.0)

    # -- description --------------------------------------------------------------
    @property
    def infer_gains(self) -> bool:
        """Whether the gains are parameters."""
        return self.gain_prior is not None

    @property
    def infer_offsets(self) -> bool:
        """Whether the offsets are parameters."""
        return self.offset_prior is not None

    @property
    def infer_background(self) -> bool:
        """Whether the background is a parameter."""
        return self.background_prior is not None

    @property
    def is_trivial(self) -> bool:
        """Unit gains, zero offsets and background, nothing inferred: Eq. 1 as it is."""
        return (np.all(np.asarray(self.gains) == 1.0) and np.all(np.asarray(self.offsets) == 0)
                and self.background == 0.0 and not self.infer_gains
                and not self.infer_offsets and not self.infer_background)

    def validate(self, n_sensors: int) -> None:
        """Refuse vectors and prior sequences that do not hold one entry per sub-sensor."""
        for name in ("gains", "offsets"):
            v = getattr(self, name)
            if np.ndim(v) and np.shape(v) != (n_sensors,):
                raise InputError(f"{name} must be a number or one value per sub-sensor, shape "
                                 f"({n_sensors},); got shape {np.shape(v)}")
        for name in ("gain_prior", "offset_prior"):
            p = getattr(self, name)
            if isinstance(p, tuple) and len(p) != n_sensors:
                raise InputError(f"{name} must be one prior or {n_sensors} (one per "
                                 f"sub-sensor); got {len(p)}")

    def names(self, n_sensors: int) -> list[str]:
        """Names of the inferred terms in layout order (``b``, ``g[n]``, ``o[n]``)."""
        out = ["b"] if self.infer_background else []
        if self.infer_gains:
            out += [f"g[{n}]" for n in range(n_sensors)]
        if self.infer_offsets:
            out += [f"o[{n}]" for n in range(n_sensors)]
        return out

    def n_free(self, n_sensors: int) -> int:
        """Number of inferred nuisance parameters."""
        return (int(self.infer_background) + n_sensors * (int(self.infer_gains)
                                                          + int(self.infer_offsets)))

    def nominal(self, n_sensors: int) -> np.ndarray:
        """The values (true or assumed) of the inferred terms, layout order."""
        parts = [np.array([self.background])] if self.infer_background else []
        if self.infer_gains:
            parts.append(np.broadcast_to(self.gains, (n_sensors,)).astype(float))
        if self.infer_offsets:
            parts.append(np.broadcast_to(self.offsets, (n_sensors,)).astype(float))
        return np.concatenate(parts) if parts else np.zeros(0)

    def priors(self, n_sensors: int) -> tuple[Prior, ...]:
        """The prior of every inferred term, layout order."""
        def each(p):
            return p if isinstance(p, tuple) else (p,) * n_sensors
        out: tuple[Prior, ...] = (self.background_prior,) if self.infer_background else ()
        if self.infer_gains:
            out += each(self.gain_prior)
        if self.infer_offsets:
            out += each(self.offset_prior)
        return out

    # -- the expected readings ------------------------------------------------------
    def split(self, eta: np.ndarray | None, n_sensors: int
              ) -> tuple[np.ndarray | float, np.ndarray | float, np.ndarray | float]:
        """``(b, g, o)`` broadcastable against (..., N), from inferred values ``eta`` (..., Q)."""
        if eta is None:
            return self.background, self.gains, self.offsets
        eta = np.asarray(eta, float)
        i = 0
        b: np.ndarray | float = self.background
        g: np.ndarray | float = self.gains
        o: np.ndarray | float = self.offsets
        if self.infer_background:
            b, i = eta[..., 0:1], 1
        if self.infer_gains:
            g, i = eta[..., i:i + n_sensors], i + n_sensors
        if self.infer_offsets:
            o = eta[..., i:i + n_sensors]
        return b, g, o

    def apply(self, response: np.ndarray, eta: np.ndarray | None = None) -> np.ndarray:
        """Expected readings ``g (r + b) + o`` (..., N) of the Eq. 1 ``response`` (..., N)."""
        b, g, o = self.split(eta, response.shape[-1])
        return g * (response + b) + o

    def jacobian(self, response: np.ndarray, eta: np.ndarray | None = None
                 ) -> tuple[np.ndarray | float, np.ndarray]:
        """``(g, d mu / d eta)``: the factor of the scene Jacobian and (..., N, Q)."""
        n = response.shape[-1]
        b, g, _ = self.split(eta, n)
        gain = np.broadcast_to(g, response.shape)
        cols = []
        if self.infer_background:
            cols.append(gain[..., None])
        eye = np.eye(n)
        if self.infer_gains:
            cols.append((response + b)[..., :, None] * eye)
        if self.infer_offsets:
            cols.append(np.broadcast_to(eye, response.shape[:-1] + (n, n)))
        jac = np.concatenate(cols, axis=-1) if cols else np.zeros(response.shape + (0,))
        return g, jac

    def __repr__(self) -> str:
        def show(v, p):
            text = f"{v!r}" if np.ndim(v) == 0 else f"<{np.size(v)} values>"
            return text + ("" if p is None else " (inferred)")
        return (f"Nuisance(gains={show(self.gains, self.gain_prior)}, "
                f"offsets={show(self.offsets, self.offset_prior)}, "
                f"background={show(self.background, self.background_prior)})")


def prior_precision(priors: tuple[Prior, ...], n_grid: int = 2048) -> np.ndarray:
    """1 / variance of each 1-D prior, shape (Q,): its information in a Gaussian picture.

    Variances by quantile integration of ``ppf`` (midpoints of ``n_grid`` cells); a
    prior with infinite variance gets 0.  Used for the Bayesian information of
    nuisance terms (CRLB with priors, Laplace evidence).
    """
    u = (np.arange(n_grid) + 0.5) / n_grid
    cache: dict[int, float] = {}
    out = np.empty(len(priors))
    for i, p in enumerate(priors):
        key = id(p)
        if key not in cache:
            x = np.asarray(p.ppf(u), float)
            var = float(np.var(x)) if np.all(np.isfinite(x)) else np.inf
            cache[key] = 0.0 if not np.isfinite(var) or var <= 0 else 1.0 / var
        out[i] = cache[key]
    return out
