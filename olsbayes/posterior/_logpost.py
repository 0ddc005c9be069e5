"""Vectorised log-posterior in the sampler's coordinates.

Periodic coordinates (ring angles, sphere longitudes) are sampled in a window
``z in (-pi, pi]`` shifted by a constant ``c`` per coordinate role: the angle
is ``z + c``.  The shift puts the window's edge (the cut of the circle) in the
largest gap between the sources, so a source near +-pi is sampled far from
any boundary, while the density on the window is exactly the density on the
circle (a translation, Jacobian 1).

Coordinates with a :class:`~olsbayes.priors.LogUniform` prior (an inferred noise
sigma, log-uniform intensities) are sampled as ``z = log x``, where that prior
is flat: a support spanning decades is then explored by the ensemble's linear
moves in a few steps, while in ``x`` a walker near the lower end proposes
jumps of the size of the upper end and almost never moves.  The sampler's
density carries the Jacobian ``log |dx/dz| = z``; :meth:`LogPosterior.jacobian`
converts it back to the density of the parameters.  Other coordinates are unchanged.
"""

from __future__ import annotations

import numpy as np

from .._one import sum_products, sum_squares
from ..circular import largest_gap_cut, wrap_angle
from ..model import BLOCK_TERMS
from ..priors import LogUniform, ScenePrior
from . import _general

__all__ = ["LogPosterior", "cut_shift"]

_LOG_2PI = float(np.log(2.0 * np.pi))
_FLOAT = np.dtype(float)


def cut_shift(prior: ScenePrior, points: np.ndarray | None) -> np.ndarray:
    """Per-parameter shifts (P,) putting the circle's cut in the largest source gap.

    ``points`` (..., P) are the walkers' start positions; None puts the cut at pi.
    Non-periodic parameters get shift 0.
    """
    shift = np.zeros(prior.n_params)
    w = prior.n_loc + 1
    k = prior.n_sources
    for j, p in enumerate(prior.location):
        if not p.periodic:
            continue
        idx = np.arange(k) * w + j
        cut = np.pi if points is None else largest_gap_cut(points[..., idx])
        shift[idx] = cut + np.pi  # window (-pi, pi] around the antipode of the cut
    return shift


class LogPosterior:
    """``log prior + log likelihood`` of flat vectors, batched over leading axes.

    Parameters
    ----------
    model : Model
    data : ndarray (N,)
    prior : ScenePrior
    shift : ndarray (P,)
        Sampler coordinates are ``z = x - shift`` (non-zero only at periodic
        parameters); periodic z must lie in (-pi, pi].  Coordinates with a
        log-uniform prior are ``z = log x`` instead (their shift must be 0).
    use_likelihood : bool
        False samples the prior (used to test the sampler).
    frames : bool
        ``data`` holds frames (F, N) of one scene.

    Models with other noise, nuisance terms or frames evaluate their likelihood
    through :mod:`olsbayes.posterior._general` (extras after the sources).
    """

    def __init__(self, model, data: np.ndarray, prior: ScenePrior, shift: np.ndarray,
                 use_likelihood: bool = True, frames: bool = False):
        self.model = model
        self.data = np.asarray(data, dtype=float)
        self.frames = bool(frames)
        self.general = _general.is_general(model, prior, self.frames)
        self.prior = prior
        self.shift = np.asarray(shift, dtype=float)
        self.periodic = prior.periodic
        self.use_likelihood = use_likelihood
        self.n_model = model.n_params(prior.n_sources)
        self.n_calls = 0
        self.log_scale = np.array([isinstance(m, LogUniform) for m in prior.marginals],
                                  dtype=bool)
        self._any_log = bool(self.log_scale.any())
        # support in sampler coordinates: the window (-pi, pi] for periodic ones
        lo = np.where(self.periodic, np.nextafter(-np.pi, 0.0), prior.lower)
        hi = np.where(self.periodic, np.pi, prior.upper)
        with np.errstate(divide="ignore"):
            self._lo = np.where(self.log_scale, np.log(np.maximum(lo, 0.0)), lo)
            self._hi = np.where(self.log_scale, np.log(np.maximum(hi, 0.0)), hi)
        sig = float(model.sigma)  # the known-noise constants of log_likelihood
        self._var = sig**2
        self._log_norm = model.n_sensors * (np.log(sig) + 0.5 * _LOG_2PI)
        # the default problem (Gaussian noise of known sigma, flat priors, linear
        # coordinates, far-field sources) has a one-pass log posterior: see _flat
        self._flat = (use_likelihood and not self.general and prior.noise is None
                      and not self._any_log and model.kind != "position"
                      and all(m.flat for m in prior.marginals))
        self._const = (float(prior.log_prob_inside(np.zeros((1, prior.n_params)))[0])
                       if self._flat else 0.0)

    def _x_of(self, z: np.ndarray) -> np.ndarray:
        """Parameters of sampler coordinates (angles not wrapped)."""
        x = z + self.shift
        if self._any_log:
            x[..., self.log_scale] = np.exp(z[..., self.log_scale])
        return x

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |dx/dz|``, shape (...,): sampler log density minus the parameters' one."""
        z = np.asarray(z, dtype=float)
        return np.sum(z[..., self.log_scale], axis=-1)

    def to_params(self, z: np.ndarray) -> np.ndarray:
        """Model parameters (angles wrapped to (-pi, pi]) of sampler coordinates."""
        x = self._x_of(np.asarray(z, dtype=float))
        x[..., self.periodic] = wrap_angle(x[..., self.periodic])
        if self._any_log:  # exp(log(upper)) may round one ulp past the support
            lo, hi = self.prior.lower[self.log_scale], self.prior.upper[self.log_scale]
            x[..., self.log_scale] = np.clip(x[..., self.log_scale], lo, hi)
        return x

    def to_sampler(self, x: np.ndarray) -> np.ndarray:
        """Sampler coordinates of model parameters (inverse of :meth:`to_params`)."""
        z = np.array(x, dtype=float) - self.shift
        z[..., self.periodic] = wrap_angle(z[..., self.periodic])
        if self._any_log:
            z[..., self.log_scale] = np.log(np.asarray(x, dtype=float)[..., self.log_scale])
        return z

    def pointwise(self, x: np.ndarray, mu: np.ndarray | None = None) -> np.ndarray:
        """Per-sub-sensor log density, shape (..., N), at model parameters.

        ``mu`` (..., N): the model's response at ``x`` when the caller has it.
        """
        if self.general:
            return _general.pointwise(self.model, self.prior, self.data, x, self.frames)
        sigma = x[..., -1:] if self.prior.noise is not None else self.model.sigma
        if mu is None:
            mu = self.model.response(x[..., : self.n_model])
        resid = (self.data - mu) / sigma
        return -0.5 * resid * resid - np.log(sigma) - 0.5 * _LOG_2PI

    def log_likelihood(self, x: np.ndarray) -> np.ndarray:
        """Total log-likelihood, shape (...,), at model parameters."""
        if self.general:
            return _general.log_likelihood(self.model, self.prior, self.data, x, self.frames)
        n = self.model.n_sensors
        mu = self.model.response(x[..., : self.n_model])
        resid = np.subtract(self.data, mu, out=mu)
        chi2 = np.einsum("...n,...n->...", resid, resid)
        if self.prior.noise is None:
            return -0.5 * chi2 / self._var - self._log_norm
        sig = x[..., -1]
        with np.errstate(divide="ignore", invalid="ignore"):
            return -0.5 * chi2 / sig**2 - n * (np.log(sig) + 0.5 * _LOG_2PI)

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(log prior, log likelihood) at sampler coordinates, each (...,).

        The log prior is the density of ``z`` (Jacobian included).
        """
        z = np.asarray(z, dtype=float)
        inside = ((z >= self._lo) & (z <= self._hi)).all(axis=-1)
        x = self._x_of(z)  # angles need no wrapping: the kernel and the prior are periodic
        lp = self.prior.log_prob_inside(x)
        if self._any_log:
            lp = lp + self.jacobian(z)
        lp = np.where(inside, lp, -np.inf)
        if not self.use_likelihood:
            return lp, np.zeros_like(lp)
        ok = np.isfinite(lp)
        if ok.all():
            return lp, self.log_likelihood(x)
        ll = np.full(lp.shape, -np.inf)
        if ok.any():
            ll[ok] = self.log_likelihood(x[ok])
        return lp, ll

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """Log posterior (up to the evidence), shape (...,) for z (..., P)."""
        self.n_calls += 1
        if (self._flat and type(z) is np.ndarray and z.ndim == 2 and z.dtype is _FLOAT
                and z.shape[0] * z.shape[1] * self.model.n_sensors <= BLOCK_TERMS):
            out = self._flat_call(z)
            if out is not None:
                return out
        lp, ll = self.split(z)
        out = lp + ll
        return np.where(np.isnan(out), -np.inf, out)

    def _flat_call(self, z: np.ndarray) -> np.ndarray | None:
        """:meth:`__call__` of the default problem for walkers z (W, P) inside the support.

        The same operations as the general path (:meth:`split`, then the
        model's batched response) on arrays of the same layout, without its
        dispatch: the prior is one constant, the response one kernel block.
        None when a walker lies outside (the general path handles it).
        """
        if not ((z >= self._lo) & (z <= self._hi)).all():
            return None
        model = self.model
        x = z + self.shift
        w, d1 = x.shape[0], model.n_loc + 1
        blocks = x.reshape(w, -1, d1)
        where = model._units(blocks[..., :-1].reshape(w, -1, d1 - 1))
        mu = np.empty((w, model.n_sensors))
        sum_products("bk,bkn->bn", blocks[..., -1], model._gain(where), out=mu)
        resid = np.subtract(self.data, mu, out=mu)
        ll = -0.5 * sum_squares(resid) / self._var - self._log_norm
        out = self._const + ll
        return np.where(np.isnan(out), -np.inf, out)
