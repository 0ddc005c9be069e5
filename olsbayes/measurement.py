"""The measurement: Eq. 1 response, then nuisance terms, then the noise model.

    r = Eq. 1 response of the sources          (:class:`~olsbayes.Model.response`)
    mu = g (r + b) + o                           (:class:`~olsbayes.nuisance.Nuisance`)
    readings ~ noise(mu)                         (:mod:`olsbayes.noise`)

The functions here are what :class:`~olsbayes.Model`'s ``check_data``,
``log_likelihood``, ``fisher`` and ``simulate`` delegate to.  A model with
Gaussian noise of known sigma and no nuisance terms (the default) takes the
original Gaussian path, arithmetic unchanged.

**Extra parameters.**  Quantities that are inferred besides the scene form an
``extra`` vector (..., Q) in a fixed order: the noise model's (``sigma`` for
:class:`~olsbayes.noise.GaussianUnknown`), then the nuisance terms' (``b``,
``g[n]``, ``o[n]``).  Functions taking ``extra=None`` evaluate them at their
nominal (true) values, :func:`extra_nominal`.  The full parameter vector of an
analysis is ``[scene (P), extra (Q)]``.

**Frames.**  ``frames=True``: data (..., F, N) are F readings of one static scene;
the log-likelihood sums over them, and the Fisher information of F frames is F
times that of one (Poisson: the exposures add).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from . import _one
from ._budget import check_memory
from ._validation import as_rng, check_reading_range, finite_array, integer, real_array
from .errors import InputError
from .noise import GaussianKnown, GaussianPerSensor, GaussianUnknown, NoiseModel, Poisson
from .nuisance import Nuisance
from .priors.univariate import LogUniform, Prior

if TYPE_CHECKING:  # pragma: no cover
    from .model import Model

__all__ = ["resolve", "extra_names", "n_extra", "extra_nominal", "extra_priors",
           "split_extra", "expected", "log_likelihood", "pointwise", "fisher", "full_fisher",
           "full_jacobian", "simulate", "check_data", "is_plain", "surrogate"]

_TRIVIAL = Nuisance()


def resolve(sigma: object, noise: object, nuisance: object, n_sensors: int
            ) -> tuple[NoiseModel, Nuisance]:
    """The noise model and nuisance record of a new model, checked against N."""
    if noise is None:
        if sigma is None:
            raise InputError("Model needs sigma (Gaussian noise sd) or noise= (a NoiseModel)")
        noise = GaussianKnown(sigma)
    elif sigma is not None:
        raise InputError("give sigma or noise=, not both (GaussianKnown(sigma) is the default)")
    elif not isinstance(noise, NoiseModel):
        raise InputError(f"noise must be an olsbayes.noise NoiseModel (GaussianKnown, "
                         f"GaussianUnknown, GaussianPerSensor, Poisson); got "
                         f"{type(noise).__name__}")
    noise.validate(n_sensors)
    if nuisance is None:
        nuisance = _TRIVIAL
    elif not isinstance(nuisance, Nuisance):
        raise InputError(f"nuisance must be an olsbayes.Nuisance; got {type(nuisance).__name__}")
    nuisance.validate(n_sensors)
    return noise, nuisance


def is_plain(model: Model) -> bool:
    """Gaussian noise of known sigma and no nuisance terms: the original path."""
    return model._plain  # fixed at construction (noise and nuisance are immutable)


# -- extra parameters -------------------------------------------------------------------
def extra_names(model: Model) -> list[str]:
    """Names of the extra parameters (noise, then nuisance), layout order."""
    return list(model.noise.inferred) + model.nuisance.names(model.n_sensors)


def n_extra(model: Model) -> int:
    """Number Q of extra parameters."""
    return len(model.noise.inferred) + model.nuisance.n_free(model.n_sensors)


def extra_nominal(model: Model) -> np.ndarray:
    """Nominal (true) values (Q,) of the extra parameters."""
    return np.concatenate([model.noise.nominal(), model.nuisance.nominal(model.n_sensors)])


def extra_priors(model: Model, sigma_prior: Prior | None = None) -> tuple[Prior, ...]:
    """Priors (Q,) of the extra parameters; sigma: ``LogUniform(sigma / 100, 100 sigma)``."""
    out: tuple[Prior, ...] = ()
    if isinstance(model.noise, GaussianUnknown):
        s = model.noise.sigma
        out = (sigma_prior if sigma_prior is not None else LogUniform(s / 100, s * 100),)
    return out + model.nuisance.priors(model.n_sensors)


def split_extra(model: Model, extra: np.ndarray | None
                ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(theta, eta)``: the noise model's and the nuisance terms' parts of ``extra``."""
    if extra is None:
        return None, None
    extra = np.asarray(extra, float)
    q = n_extra(model)
    if extra.ndim == 0 or extra.shape[-1] != q:
        raise InputError(f"extra must have last axis of length {q} ({extra_names(model)}); "
                         f"got shape {extra.shape}")
    qt = len(model.noise.inferred)
    return (extra[..., :qt] if qt else None), (extra[..., qt:] if q > qt else None)


# -- statistics ---------------------------------------------------------------------------
def check_data(model: Model, data: object, name: str = "data", frames: bool = False
               ) -> np.ndarray:
    """Readings checked for the model's noise (see :meth:`olsbayes.Model.check_data`)."""
    if model.noise.is_default and not frames:
        arr = finite_array(name, data, last=model.n_sensors)
        check_reading_range(name, arr, model.sigma)
        return arr
    arr = model.noise.check_data(data, model.n_sensors, frames=frames, name=name)
    if model.noise.kind != "poisson":
        check_reading_range(name, arr, model.sigma)
    return arr


def expected(model: Model, x: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
    """Expected readings (..., N) before noise: ``g (r + b) + o`` of the response r."""
    r = model.response(x)
    if model.nuisance.is_trivial:
        return r
    return model.nuisance.apply(r, split_extra(model, extra)[1])


def _gaussian_log_likelihood(model: Model, x: np.ndarray, data: np.ndarray) -> np.ndarray:
    """The original Gaussian known-sigma log-likelihood (the default path)."""
    if x.ndim == 1 and data.ndim == 1 and model._kind != "position":
        return _one.log_likelihood(model, x, data)
    mu = model._response_unchecked(x)
    resid = np.subtract(data, mu, out=mu) if _fits_into(data.shape, mu.shape) else (
        data - mu)  # in place when it fits: no second (..., N) array
    chi2 = _one.sum_squares(resid) / model.sigma**2
    return -0.5 * chi2 - model._log_norm


def _fits_into(small: tuple[int, ...], big: tuple[int, ...]) -> bool:
    """Whether ``small`` broadcasts to ``big`` without enlarging it."""
    if len(small) > len(big):
        return False
    return all(a in (1, b) for a, b in zip(reversed(small), reversed(big)))


def log_likelihood(model: Model, scene_or_params: object, data: object, *,
                   extra: np.ndarray | None = None, frames: bool = False) -> np.ndarray:
    """log p(data | params, extra), batched (see :meth:`olsbayes.Model.log_likelihood`)."""
    data = real_array("data", data)
    if data.ndim == 0 or data.shape[-1] != model.n_sensors:
        raise InputError(
            f"data must have last axis of length {model.n_sensors}; got shape {data.shape}")
    x = model._as_params(scene_or_params)
    if is_plain(model) and not frames and extra is None:
        return _gaussian_log_likelihood(model, x, data)
    if frames and data.ndim < 2:
        raise InputError(f"data with frames must have shape (..., F, {model.n_sensors}); "
                         f"got shape {data.shape}")
    theta = split_extra(model, extra)[0]
    return model.noise.log_likelihood(expected(model, x, extra), data, frames=frames,
                                      theta=theta)


def pointwise(model: Model, x: np.ndarray, data: np.ndarray, *,
              extra: np.ndarray | None = None, frames: bool = False) -> np.ndarray:
    """Log density per sub-sensor (..., N), summed over frames."""
    theta = split_extra(model, extra)[0]
    return model.noise.pointwise(expected(model, x, extra), data, frames=frames, theta=theta)


def _frames_default(model: Model, n_frames: int | None) -> int:
    return 1 if n_frames is None else integer("n_frames", n_frames, low=1)


def fisher(model: Model, scene_or_params: object, *, extra: np.ndarray | None = None,
           n_frames: int | None = None) -> np.ndarray:
    """Fisher information of the scene parameters (..., P, P), extras held fixed."""
    if is_plain(model) and n_frames is None and extra is None:
        jac = model.jacobian(scene_or_params)
        return np.swapaxes(jac, -1, -2) @ jac / model.sigma**2
    x = model._as_params(scene_or_params)
    theta, eta = split_extra(model, extra)
    r = model.response(x)
    g, _ = model.nuisance.jacobian(r, eta)
    jac = np.asarray(g)[..., :, None] * model.jacobian(x) if np.ndim(g) else g * model.jacobian(x)
    w = model.noise.weights(model.nuisance.apply(r, eta), n_frames=_frames_default(
        model, n_frames), theta=theta)
    return np.swapaxes(jac, -1, -2) @ (w[..., :, None] * jac)


def full_jacobian(model: Model, x: np.ndarray, extra: np.ndarray | None = None
                  ) -> np.ndarray:
    """d mu / d [scene, nuisance extras] (..., N, P + Q_nuisance) (sigma does not enter mu)."""
    r = model.response(x)
    g, jn = model.nuisance.jacobian(r, split_extra(model, extra)[1])
    js = np.asarray(g)[..., :, None] * model.jacobian(x) if np.ndim(g) else g * model.jacobian(x)
    return np.concatenate([js, np.broadcast_to(jn, js.shape[:-1] + jn.shape[-1:])], axis=-1)


def full_fisher(model: Model, scene_or_params: object, extra: np.ndarray | None = None, *,
                n_frames: int | None = None) -> np.ndarray:
    """Fisher information of ``[scene, extra]`` (..., P + Q, P + Q), the likelihood's only.

    Layout ``[scene (P), noise parameters, nuisance terms]``; the noise
    parameters' block comes from the noise model (no cross terms with the mean).
    Prior information is not included (see :func:`olsbayes.bounds.crlb`).
    """
    x = model._as_params(scene_or_params)
    theta, eta = split_extra(model, extra)
    nf = _frames_default(model, n_frames)
    a = full_jacobian(model, x, extra)
    mu = expected(model, x, extra)
    w = model.noise.weights(mu, n_frames=nf, theta=theta)
    f_mean = np.swapaxes(a, -1, -2) @ (w[..., :, None] * a)
    p, qt = model.n_params(model.n_sources_of(x)), len(model.noise.inferred)
    size = f_mean.shape[-1] + qt
    out = np.zeros(f_mean.shape[:-2] + (size, size))
    keep = np.r_[0:p, p + qt:size]
    out[..., keep[:, None], keep] = f_mean
    if qt:
        out[..., p:p + qt, p:p + qt] = model.noise.theta_information(mu, n_frames=nf,
                                                                     theta=theta)
    return out


def simulate(model: Model, scene: object, *, rng: object = None,
             size: int | tuple[int, ...] | None = None,
             n_frames: int | None = None) -> np.ndarray:
    """Noisy readings ``size + (N,)`` (frames: ``size + (F, N)``) at the nominal extras."""
    gen = as_rng(rng)
    sizes = () if size is None else (size,) if np.ndim(size) == 0 else tuple(size)
    shape = tuple(integer("size", n, low=0) for n in sizes)
    f = None if n_frames is None else integer("n_frames", n_frames, low=1)
    if is_plain(model) and f is None:
        mu = model.response(scene)
        _check_readings(shape, mu.shape, 1)
        return mu + model.sigma * gen.standard_normal(shape + mu.shape)
    mu = expected(model, model._as_params(scene), None)
    _check_readings(shape, mu.shape, 1 if f is None else f)
    return model.noise.simulate(mu, gen, shape, f)


def _check_readings(shape: tuple[int, ...], mu_shape: tuple[int, ...], n_frames: int) -> None:
    """The memory of ``shape + mu_shape`` readings of ``n_frames`` frames, before drawing.

    Two arrays of that size at once (the noise and the readings).
    """
    count = float(np.prod(shape, dtype=float)) * float(np.prod(mu_shape, dtype=float)) * n_frames
    check_memory(f"simulate of {count:,.0f} readings (size {shape}, {n_frames} frame(s) of "
                 f"{mu_shape})", 16.0 * count)


# -- the Gaussian surrogate --------------------------------------------------------------
#: Quantile of the (calibrated) readings that starts an inferred background.
BACKGROUND_QUANTILE = 0.1


def _summary(model: Model, s: np.ndarray, frames: bool) -> tuple[np.ndarray, float, int]:
    """(mean reading (T, N) in rate units, surrogate sd of it, frames F)."""
    n_f = s.shape[1] if frames else 1
    noise = model.noise
    if isinstance(noise, Poisson):
        counts = s.sum(axis=1) if frames else s
        e = noise.total_exposure(n_f)
        sd = float(np.sqrt(max(float(np.mean(counts)), 1.0))) / e
        return counts / e - noise.dark, sd, n_f
    mean = s.mean(axis=1) if frames else s
    if isinstance(noise, GaussianPerSensor):
        return mean, float(np.sqrt(np.mean(noise.sigma**2))) / np.sqrt(n_f), n_f
    return mean, noise.scale / np.sqrt(n_f), n_f


def surrogate(model: Model, s: np.ndarray, frames: bool
              ) -> tuple[Model, np.ndarray, np.ndarray, bool]:
    """Gaussian known-sigma surrogate of a batch: (model, readings (T, N), eta0, exact).

    ``eta0`` (T, Q_nuisance) starts the inferred nuisance terms; ``exact`` is True
    when the surrogate's least squares is the model's own likelihood.
    """
    nu = model.nuisance
    mean, sd, _ = _summary(model, s, frames)
    eta0 = np.broadcast_to(nu.nominal(model.n_sensors), (s.shape[0], nu.n_free(
        model.n_sensors))).copy()
    g, o = np.asarray(nu.gains, float), np.asarray(nu.offsets, float)
    y = (mean - o) / g
    if nu.infer_background:
        lo, hi = nu.background_prior.lower, nu.background_prior.upper
        b0 = np.clip(np.quantile(y, BACKGROUND_QUANTILE, axis=-1), lo, hi)
        eta0[:, 0] = b0
        y = y - b0[:, None]
    else:
        y = y - nu.background
    sigma = sd / float(np.sqrt(np.mean(g**2)))
    scale = float(np.max(np.abs(y))) if y.size else 1.0
    sigma = min(max(sigma, 1e-12 * max(scale, 1e-300)), 1e12 * max(scale, 1e-300))
    gauss = type(model)(model.array, sigma, model.sensitivity)
    exact = (isinstance(model.noise, (GaussianKnown, GaussianUnknown)) and g.ndim == 0
             and nu.n_free(model.n_sensors) == 0)
    return gauss, y, eta0, exact
