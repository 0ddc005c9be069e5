"""Joint prior of a K-source scene in the model's flat parameter layout.

Notes on exchangeable sources and K!
------------------------------------
:class:`ScenePrior` is a product of *the same* 1-D priors for every source, so
its density is symmetric under any permutation of the K source blocks: it is
the density of the **labelled** (unordered, exchangeable) parameter vector on
the full product space, normalised to 1 there.  Consequences:

* ``log_prob``, ``ppf`` and ``sample`` all work on the full labelled space;
  an evidence computed with them (nested sampling over ``ppf``, or a Laplace
  approximation integrated over the whole space) is the evidence of the
  K-source model and needs **no** K! correction: the K! symmetric copies of
  each mode are all inside the integral.
* If instead one integrates only over the canonical wedge (sources in one
  chosen order), the prior restricted to that wedge integrates to 1/K!, so the
  normalised ordered prior is ``log_prob(x) + log K!`` (``log_prob_ordered``)
  and an evidence integrated over the wedge with ``log_prob`` must be
  multiplied by K! (add ``log_label_factor`` = log K!).  A Laplace
  approximation around one labelled mode counts one of K! copies: add
  ``log_label_factor`` when the modes are well separated.

The optional noise parameter ``sigma`` (when inferred) is appended last.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_rng, integer
from ..circular import wrap_angle
from ..errors import InputError
from .univariate import CircularUniform, Prior, SinLatitude

__all__ = ["ScenePrior"]

_HALF_PI = np.pi / 2 + 1e-12
_RANGES = {
    "angle": [("theta", -np.pi - 1e-12, np.pi + 1e-12)],
    "lonlat": [("lon", -np.pi - 1e-12, np.pi + 1e-12), ("lat", -_HALF_PI, _HALF_PI)],
    "position": [("x", -np.inf, np.inf), ("y", -np.inf, np.inf), ("z", 0.0, np.inf)],
}


def _check_prior(name: str, prior: object, lo: float, hi: float, what: str) -> Prior:
    if not isinstance(prior, Prior):
        raise InputError(
            f"{name} must be an olsbayes.priors prior (Uniform, CircularUniform, ...); "
            f"got {type(prior).__name__}"
        )
    if prior.lower < lo or prior.upper > hi:
        raise InputError(
            f"{name} = {prior!r} has support [{prior.lower:.6g}, {prior.upper:.6g}] "
            f"outside the accepted range [{lo:.6g}, {hi:.6g}] for {what}"
        )
    return prior


class ScenePrior:
    """Product prior of K exchangeable sources (and optionally the noise sigma).

    Parameters
    ----------
    model : Model
        Fixes the geometry (``model.kind``) and the flat layout.
    n_sources : int
        K >= 0.
    intensity : Prior
        Prior of every intensity, support within [0, inf).
    location : sequence of Prior, optional
        One prior per location coordinate, shared by all sources.  Defaults:
        ring ``(CircularUniform(),)``; sphere ``(CircularUniform(), SinLatitude())``
        (isotropic); a plate has no default (give a box).  Angles must have
        support within [-pi, pi], latitudes within [-pi/2, pi/2], plate heights z
        within [0, inf).
    noise : Prior, optional
        Prior of the noise sd ``sigma`` when it is inferred (e.g. ``LogUniform``);
        None (default) means sigma is known, ``model.sigma``.
    extra : sequence of (name, Prior), optional
        Priors of the model's extra parameters (an unknown sigma, background,
        gains, offsets; :func:`olsbayes.measurement.extra_names`), appended after
        the sources; not together with ``noise``.

    Notes
    -----
    The density is that of the *labelled* parameters on the full product space
    (see the module notes on K!): ``log_prob``/``ppf`` evidences need no K!
    correction; a Laplace value around one labelled mode adds ``log_label_factor``.
    """

    def __init__(
        self,
        model,
        n_sources: int,
        intensity: Prior,
        location: tuple[Prior, ...] | list[Prior] | None = None,
        noise: Prior | None = None,
        extra: tuple[tuple[str, Prior], ...] | list | None = None,
    ):
        self.kind = model.kind
        self.n_loc = model.n_loc
        self.n_sources = integer("n_sources", n_sources, low=0)
        self.sigma = model.sigma
        self._names = model.param_names(self.n_sources)
        ranges = _RANGES[self.kind]
        if location is None:
            if self.kind == "position":
                raise InputError("location priors are required for a plate: give a box "
                                 "(three priors for x, y, z) or use default_priors(box=...)")
            location = (CircularUniform(),) if self.kind == "angle" else (
                CircularUniform(), SinLatitude())
        location = tuple(location) if isinstance(location, (list, tuple)) else (location,)
        if len(location) != self.n_loc:
            raise InputError(
                f"location must hold {self.n_loc} prior(s) ({', '.join(r[0] for r in ranges)}) "
                f"for a {self.kind!r} array; got {len(location)}"
            )
        self.location = tuple(
            _check_prior(f"location prior of {nm}", p, lo, hi, f"{nm} of a {self.kind!r} array")
            for p, (nm, lo, hi) in zip(location, ranges)
        )
        self.intensity = _check_prior("intensity", intensity, 0.0, np.inf, "intensities")
        self.noise = None if noise is None else _check_prior(
            "noise", noise, 0.0, np.inf, "the noise sd sigma")
        extra = tuple(extra or ())
        if extra and noise is not None:
            raise InputError("give noise= (sigma of a Gaussian model) or extra=, not both")
        if any(not (isinstance(e, tuple) and len(e) == 2 and isinstance(e[0], str))
               for e in extra):
            raise InputError("extra must be a sequence of (name, Prior) pairs")
        self.extra = tuple((nm, _check_prior(f"prior of {nm}", p, -np.inf, np.inf, nm))
                           for nm, p in extra)

    # -- layout -----------------------------------------------------------------
    @property
    def n_params(self) -> int:
        """P = K (d + 1), plus one when sigma is inferred, plus the extras."""
        return self.n_sources * (self.n_loc + 1) + (self.noise is not None) + len(self.extra)

    @property
    def extra_names(self) -> list[str]:
        """Names of the extra parameters (after the sources)."""
        return [nm for nm, _ in self.extra]

    @property
    def param_names(self) -> list[str]:
        """Names in layout order (``model.param_names(K)`` then ``"sigma"`` or the extras)."""
        return self._names + (["sigma"] if self.noise is not None else []) + self.extra_names

    @property
    def marginals(self) -> tuple[Prior, ...]:
        """The 1-D prior of every flat parameter, length P."""
        per = self.location + (self.intensity,)
        out = per * self.n_sources
        return (out + ((self.noise,) if self.noise is not None else ())
                + tuple(p for _, p in self.extra))

    @property
    def periodic(self) -> np.ndarray:
        """Boolean mask (P,) of periodic parameters (ring angles, longitudes)."""
        return np.array([p.periodic for p in self.marginals], dtype=bool)

    @property
    def periodic_indices(self) -> list[int]:
        """Indices of periodic parameters, for dynesty's ``periodic=``."""
        return [int(i) for i in np.flatnonzero(self.periodic)]

    @property
    def lower(self) -> np.ndarray:
        """Lower ends of the supports, shape (P,)."""
        return np.array([p.lower for p in self.marginals])

    @property
    def upper(self) -> np.ndarray:
        """Upper ends of the supports, shape (P,)."""
        return np.array([p.upper for p in self.marginals])

    @property
    def log_label_factor(self) -> float:
        """log K!: the number of labelled copies of each unordered scene."""
        from scipy.special import gammaln  # on use: scipy is slow to import
        return float(gammaln(self.n_sources + 1.0))

    def _groups(self):
        """(prior, index array) pairs, one per distinct coordinate role."""
        w = self.n_loc + 1
        k = np.arange(self.n_sources) * w
        groups = [(p, k + j) for j, p in enumerate(self.location + (self.intensity,))]
        if self.noise is not None:
            groups.append((self.noise, np.array([self.n_params - 1])))
        same: dict[int, tuple[Prior, list[int]]] = {}  # one group per distinct prior object
        for j, (_, p) in enumerate(self.extra):
            same.setdefault(id(p), (p, []))[1].append(self.n_sources * w + j)
        groups += [(p, np.array(idx)) for p, idx in same.values()]
        return groups

    def _check(self, name: str, x: object) -> np.ndarray:
        arr = np.asarray(x, dtype=float)
        if arr.ndim == 0 or arr.shape[-1] != self.n_params:
            raise InputError(
                f"{name} must have last axis of length {self.n_params} ({self.param_names}); "
                f"got shape {arr.shape}"
            )
        return arr

    # -- densities and transforms -------------------------------------------------
    def log_prob(self, x: np.ndarray) -> np.ndarray:
        """Joint log density of labelled parameters, shape (...,) for x (..., P).

        One pass over the flat array: a support test against ``lower``/``upper``
        (periodic coordinates wrap, so they are always inside) plus the density
        of each coordinate role; constant densities cost nothing per call.
        """
        x = self._check("x", x)
        fast = self._fast
        cols = x[..., fast["bounded"]]
        inside = np.all((cols >= fast["lo"]) & (cols <= fast["hi"]), axis=-1)
        total = self.log_prob_inside(x)
        out = np.where(inside & ~np.isnan(total), total, -np.inf)
        return out if out.ndim else float(out)

    def log_prob_inside(self, x: np.ndarray) -> np.ndarray:
        """:meth:`log_prob` without the support test: for x known to be inside.

        Samplers that test the support themselves (in their own coordinates)
        call this to save a pass over the array; outside the support the value
        is meaningless.
        """
        fast = self._fast
        total = np.full(np.shape(x)[:-1], fast["const"])
        for prior, idx in fast["curved"]:
            xi = x[..., idx]
            if prior.periodic:
                xi = wrap_angle(xi)
            xi = np.clip(xi, prior.lower, prior.upper)
            with np.errstate(divide="ignore", invalid="ignore"):
                total = total + np.sum(prior._log_pdf(xi), axis=-1)
        return total

    @property
    def _fast(self) -> dict:
        if not hasattr(self, "_fast_cache"):
            margs = self.marginals
            bounded = np.array([not p.periodic for p in margs], dtype=bool)
            const = 0.0
            curved = []
            for prior, idx in self._groups():
                if idx.size and prior.flat:
                    const += idx.size * float(prior._log_pdf(np.zeros(1))[0])
                elif idx.size:
                    curved.append((prior, idx))
            self._fast_cache = dict(
                bounded=bounded, lo=self.lower[bounded], hi=self.upper[bounded],
                const=const, curved=curved)
        return self._fast_cache

    def log_prob_ordered(self, x: np.ndarray) -> np.ndarray:
        """Normalised density on the canonical wedge: ``log_prob(x) + log K!``."""
        return self.log_prob(x) + self.log_label_factor

    def ppf(self, u: np.ndarray) -> np.ndarray:
        """Unit cube (..., P) to parameters (..., P): dynesty's prior transform."""
        u = self._check("u", u)
        out = np.empty_like(u)
        for prior, idx in self._groups():
            out[..., idx] = prior.ppf(u[..., idx])
        return out

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Parameters (..., P) to the unit cube, inverse of :meth:`ppf`."""
        x = self._check("x", x)
        out = np.empty_like(x)
        for prior, idx in self._groups():
            out[..., idx] = prior.cdf(x[..., idx])
        return out

    def sample(self, size: int | tuple[int, ...] | None = None, *,
               rng: object = None) -> np.ndarray:
        """Independent prior draws, shape ``size + (P,)``."""
        gen = as_rng(rng)
        shape = () if size is None else tuple(np.atleast_1d(size).astype(int))
        return self.ppf(gen.random(shape + (self.n_params,)))

    def contains(self, x: np.ndarray) -> np.ndarray:
        """True where ``log_prob(x)`` is finite, shape (...,)."""
        return np.isfinite(self.log_prob(x))

    def __repr__(self) -> str:
        extra = f", extra=<{len(self.extra)} priors>" if self.extra else ""
        return (
            f"ScenePrior(kind={self.kind!r}, n_sources={self.n_sources}, "
            f"location={self.location!r}, intensity={self.intensity!r}, noise={self.noise!r}"
            f"{extra})"
        )
