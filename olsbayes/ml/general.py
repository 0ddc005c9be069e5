"""ML fits for every noise model, nuisance terms and repeated frames.

The global search of :func:`olsbayes.ml.fit_ml` is built for Gaussian noise of
one known sigma.  Any other measurement is first mapped onto such a
*surrogate*: frames averaged (Poisson: counts summed and divided by the total
exposure, the dark rate subtracted), known offsets, gains and background undone,
the inferred background started at a low quantile of the readings, and sigma set
to the surrogate's noise level.  The surrogate's fit (any method) is the start;
then

* where the surrogate's least squares *is* the likelihood -- Gaussian noise of
  known or unknown sigma, one gain for every sub-sensor, nothing inferred but
  sigma -- its estimate is the ML estimate (an unknown sigma then takes its
  profile value sqrt(RSS / (F N)), biased low by the factor sqrt(1 - P / (F N)));
* otherwise damped Fisher scoring on the model's own likelihood refines the
  scene and the nuisance terms jointly (:mod:`olsbayes.ml.irls`; Poisson: the
  deviance, iteratively reweighted).

The covariance reported is the inverse of the information of the scene with
every inferred extra marginalised (:func:`olsbayes.bounds.marginal_information`,
nuisance priors included).
"""

from __future__ import annotations

import numpy as np

from .. import measurement
from .._validation import flag, integer
from ..bounds import bayesian_information, bound_covariance, marginal_information
from ..errors import InputError
from ..measurement import surrogate
from ..model import Model
from ..noise import GaussianKnown, GaussianUnknown
from .irls import profile_sigma, refine_general
from .plain import fit_plain, warn_rivals
from .result import MLResult

__all__ = ["fit_general", "check_general_inputs"]


def check_general_inputs(model: object, data: object, n_sources: object, frames: object
                         ) -> tuple[np.ndarray, int, bool]:
    """Validated readings as a batch (T, N) or (T, F, N), K and whether it was a batch."""
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    frames = flag("frames", frames)
    arr = model.check_data(data, frames=frames)
    single = 2 if frames else 1
    if arr.ndim not in (single, single + 1):
        shape = "(F, N) or (T, F, N)" if frames else "(N,) or (T, N)"
        raise InputError(f"data must have shape {shape} with N = {model.n_sensors}; "
                         f"got {arr.shape}")
    k_max = max(model.n_sensors // (model.n_loc + 1), 1)
    k = integer("n_sources", n_sources, low=1, high=k_max)
    return (arr if arr.ndim == single + 1 else arr[None]), k, arr.ndim == single + 1


def _statistics(model: Model, x: np.ndarray, extra: np.ndarray, s: np.ndarray, frames: bool
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log L (T,), scene covariance with the extras marginalised (T, P, P), extras' sd (T, Q)."""
    n_f = s.shape[1] if frames else None
    ex = extra if extra.shape[-1] else None
    ll = model.log_likelihood(x, s, extra=ex, frames=frames)
    full = bayesian_information(model, x, ex, n_frames=n_f)
    p = x.shape[-1]
    cov = bound_covariance(marginal_information(full, p))[0]
    extra_cov = bound_covariance(full)[0]
    extra_sd = np.sqrt(np.diagonal(extra_cov, axis1=-2, axis2=-1)[..., p:])
    return ll, cov, extra_sd


#: Offsets of the extra starts, in units of each location's surrogate sd.
START_OFFSETS = (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0)


def _starts(model: Model, x0: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Starts (T, S, P): x0 and each source location moved by :data:`START_OFFSETS` sds.

    The likelihood of a kinked law has local optima on either side of a
    sub-sensor's horizon (where a source starts or stops lighting it); a start on
    each side lets the refinement reach both.  The offsets are capped at a
    quarter of a radian (a fifth of the plate's extent for near sources).
    """
    t, p = x0.shape
    d1 = model.n_loc + 1
    cap = 0.25 if model.kind != "position" else 0.2 * float(np.ptp(model.array.positions))
    step = np.minimum(np.where(np.isfinite(sd), sd, cap), cap)
    out = [x0]
    for j in range(p):
        if j % d1 == d1 - 1:
            continue  # intensities need no extra starts: the likelihood is smooth in them
        for c in START_OFFSETS:
            x = x0.copy()
            x[:, j] += c * step[:, j]
            out.append(x)
    return np.stack(out, axis=1)


def _refine(model: Model, s: np.ndarray, x0: np.ndarray, sd: np.ndarray, eta0: np.ndarray,
            frames: bool):
    """Refine from every start of :func:`_starts`, keep the best, polish on kinks.

    The polish holds the locations and refines intensities and nuisance terms: a
    source on a horizon stalls the joint step while the others can still improve.
    """
    from .irls import GeneralOutcome

    t = s.shape[0]
    starts = _starts(model, x0, sd)
    n_s = starts.shape[1]
    rep = np.repeat(s, n_s, axis=0)
    out = refine_general(model, rep, starts.reshape(t * n_s, -1), np.repeat(eta0, n_s, axis=0),
                         frames=frames)
    obj = out.objective.reshape(t, n_s)
    best = np.argmin(np.where(np.isfinite(obj), obj, np.inf), axis=1)
    pick = np.arange(t) * n_s + best
    nev = out.n_evaluations.reshape(t, n_s).sum(axis=1)
    loc = np.ones(x0.shape[1], bool)
    loc[model.n_loc::model.n_loc + 1] = False
    x, extra = out.x[pick], out.extra[pick]
    qt = len(model.noise.inferred)
    pol = refine_general(model, s, x, extra[:, qt:], frames=frames, frozen=loc)
    better = pol.objective < out.objective[pick]
    x = np.where(better[:, None], pol.x, x)
    extra = np.where(better[:, None], pol.extra, extra)
    return GeneralOutcome(x=x, extra=extra, objective=np.minimum(pol.objective,
                          out.objective[pick]), converged=out.converged[pick],
                          n_evaluations=nev + pol.n_evaluations)


def fit_general(model: Model, data: object, n_sources: object, method: str = "fast", *,
                options: object = None, grid: np.ndarray | None = None, rng: object = None,
                warn: bool = True, frames: bool = False) -> MLResult:
    """ML fit of a model with any noise, nuisance terms or frames (see the module notes).

    The arguments are those of :func:`olsbayes.ml.fit_ml`.  The result's
    ``extra`` holds the inferred extras (``extra_names``) with their sd.
    """
    s, k, batch = check_general_inputs(model, data, n_sources, frames)
    gauss, y, eta0, exact = surrogate(model, s, bool(frames))
    start = fit_plain(gauss, y, k, method, options=options, grid=grid, rng=rng, warn=False)
    x0 = np.asarray(start.params, float)
    if exact:
        x = x0
        conv, nev = np.asarray(start.converged), np.asarray(start.n_evaluations)
        extra = np.zeros((s.shape[0], 0))
        if isinstance(model.noise, GaussianUnknown):
            mu = measurement.expected(model, x)
            extra = profile_sigma(model, mu, s, bool(frames))
        gap = np.asarray(start.rival_gap)
    else:
        out = _refine(model, s, x0, np.asarray(start.std, float).reshape(x0.shape), eta0,
                      bool(frames))
        x, extra = model.canonical(out.x), out.extra
        conv, nev = out.converged, np.asarray(start.n_evaluations) + out.n_evaluations
        gap = np.full(s.shape[0], np.nan)  # rivals are assessed on the surrogate only
    ll, cov, extra_sd = _statistics(model, x, extra, s, bool(frames))
    if exact and isinstance(model.noise, GaussianKnown):
        cov = np.asarray(start.cov).reshape(cov.shape)  # the same matrix, as the surrogate's
    if warn:
        warn_rivals(method, np.where(np.isnan(gap), np.inf, gap), conv)
    sel = (lambda a: a) if batch else (lambda a: a[0])
    return MLResult(params=sel(x), log_likelihood=sel(ll), converged=sel(conv),
                    n_evaluations=sel(nev), cov=sel(cov), rival_gap=sel(gap), method=method,
                    n_sources=k, model=model, extra=sel(extra), extra_std=sel(extra_sd),
                    extra_names=tuple(measurement.extra_names(model)))
