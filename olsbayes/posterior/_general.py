"""Posterior pieces for models beyond Gaussian noise of known sigma.

A model with another noise (:mod:`olsbayes.noise`), nuisance terms or frames
has its extra parameters (an unknown sigma, background, gains, offsets)
appended to the sources' in the prior (``ScenePrior.extra``) and so in every
draw.  Here: the likelihood of a draw, the walkers' centre and ball, the CRLB at
the estimate, and the posterior predictive.

**Stored readings.**  Frames are summarised by their sufficient statistic per
sub-sensor -- summed counts (Poisson) or the mean reading (Gaussian) -- which is
what ``observed_data`` and the ``posterior_predictive`` group hold, shape (N,);
the pointwise log-likelihood sums the frames.  Without frames it is the readings.
The model check's discrepancy is then Pearson's chi^2 of that statistic,
``sum w_n (rate_n - mu_n)^2`` with the noise model's Fisher weights (Poisson:
``(S - Lambda)^2 / Lambda``).
"""

from __future__ import annotations

import numpy as np

from .. import measurement
from ..bounds import bayesian_information, bound_covariance
from ..errors import InputError
from ..model import Model
from ..noise import GaussianUnknown, Poisson
from ..priors import ScenePrior

__all__ = ["is_general", "check_prior_extras", "log_likelihood", "pointwise", "ml_centre",
           "information", "crlb_covariance", "statistic", "predictive", "pearson"]


def is_general(model: Model, prior: ScenePrior | None = None, frames: bool = False) -> bool:
    """Whether the model (or prior, or frames) leaves the original Gaussian path."""
    return frames or not measurement.is_plain(model) or bool(prior is not None and prior.extra)


def check_prior_extras(model: Model, prior: ScenePrior) -> None:
    """The prior must carry exactly the model's extra parameters, in its order."""
    want = measurement.extra_names(model)
    if prior.extra_names != want:
        raise InputError(f"priors must hold the model's extra parameters {want} (see "
                         f"default_priors); got {prior.extra_names}")
    if want and prior.noise is not None:
        raise InputError("priors: noise= is for a Gaussian model of known sigma; this model "
                         "infers its extras through ScenePrior(extra=...)")


def _parts(model: Model, prior: ScenePrior, x: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray | None]:
    p = model.n_params(prior.n_sources)
    return x[..., :p], (x[..., p:] if prior.extra else None)


def log_likelihood(model: Model, prior: ScenePrior, data: np.ndarray, x: np.ndarray,
                   frames: bool) -> np.ndarray:
    """log L (...,) of draws x (..., P)."""
    xs, ex = _parts(model, prior, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        return measurement.log_likelihood(model, xs, data, extra=ex, frames=frames)


def pointwise(model: Model, prior: ScenePrior, data: np.ndarray, x: np.ndarray,
              frames: bool) -> np.ndarray:
    """Per-sub-sensor log-likelihood (..., N) of draws x (..., P), frames summed."""
    xs, ex = _parts(model, prior, x)
    return measurement.pointwise(model, xs, data, extra=ex, frames=frames)


def ml_centre(model: Model, data: np.ndarray, prior: ScenePrior, start: object,
              gen: np.random.Generator, frames: bool) -> np.ndarray:
    """The ML point with its extras (P,): from ``start`` (an MLResult) or a new fit."""
    from ..ml import MLResult, fit_ml

    fit = start if isinstance(start, MLResult) else fit_ml(
        model, data, prior.n_sources, rng=gen, warn=False, frames=frames)
    extra = np.asarray(fit.extra, float)
    if extra.size != len(prior.extra):
        raise InputError(f"start: the MLResult holds {extra.size} extra parameters; the "
                         f"prior has {len(prior.extra)}")
    return np.concatenate([np.asarray(fit.params, float), extra])


def _n_frames(data: np.ndarray, frames: bool) -> int | None:
    return int(data.shape[-2]) if frames else None


def information(model: Model, prior: ScenePrior, x: np.ndarray, n_frames: int | None
                ) -> np.ndarray:
    """Full information (P, P) at a point: likelihood plus the nuisance priors."""
    xs, ex = _parts(model, prior, x)
    return bayesian_information(model, xs, ex, n_frames=n_frames)


def crlb_covariance(model: Model, prior: ScenePrior, x: np.ndarray, n_frames: int | None
                    ) -> np.ndarray:
    """Bound (P, P) at ``x``: inverse of :func:`information` (extras marginalised)."""
    return bound_covariance(information(model, prior, x, n_frames))[0]


def statistic(model: Model, data: np.ndarray, frames: bool) -> np.ndarray:
    """Readings (N,) stored as observed: the frames' summed counts or mean, or the data."""
    if not frames:
        return data
    return data.sum(axis=-2) if isinstance(model.noise, Poisson) else data.mean(axis=-2)


def _sd(model: Model, ex: np.ndarray | None) -> np.ndarray | float:
    """Gaussian sd per draw (..., 1) or fixed, from the draws' extras."""
    if isinstance(model.noise, GaussianUnknown) and ex is not None:
        return ex[..., 0:1]
    return getattr(model.noise, "sigma", model.sigma)


def predictive(model: Model, prior: ScenePrior, x: np.ndarray, gen: np.random.Generator,
               n_frames: int | None) -> np.ndarray:
    """One replicate of the stored statistic (..., N) per draw x (..., P)."""
    xs, ex = _parts(model, prior, x)
    mu = measurement.expected(model, xs, ex)
    f = 1 if n_frames is None else n_frames
    if isinstance(model.noise, Poisson):
        lam = model.noise.total_exposure(f) * np.maximum(mu + model.noise.dark, 0.0)
        return gen.poisson(lam).astype(float)
    return mu + _sd(model, ex) / np.sqrt(f) * gen.standard_normal(mu.shape)


def pearson(model: Model, prior: ScenePrior, stat: np.ndarray, x: np.ndarray,
            n_frames: int | None) -> np.ndarray:
    """Pearson's chi^2 (...,) of statistics ``stat`` (..., N) at draws x (..., P)."""
    xs, ex = _parts(model, prior, x)
    mu = measurement.expected(model, xs, ex)
    f = 1 if n_frames is None else n_frames
    theta = ex[..., :1] if isinstance(model.noise, GaussianUnknown) and ex is not None else None
    w = model.noise.weights(mu, n_frames=f, theta=theta)
    if isinstance(model.noise, Poisson):
        rate = stat / model.noise.total_exposure(f) - model.noise.dark
    else:
        rate = stat
    return np.sum(w * (rate - mu) ** 2, axis=-1)
