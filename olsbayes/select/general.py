"""Evidence for K sources under any noise model, nuisance terms and frames.

The extra parameters (an unknown sigma, background, gains, offsets) are
integrated with the scene's, under their priors (``ScenePrior.extra``):

* K = 0: without extras the evidence is the likelihood of the expected readings
  of no source; with one extra (e.g. an unknown sigma) it is integrated by
  quadrature on 20001 points of the prior's unit interval (``ppf``); with more,
  by the Laplace rule around their ML point.
* K >= 1: the Laplace rule at the ML point of :func:`olsbayes.ml.fit_ml` with the
  full information of scene and extras -- the likelihood's Fisher matrix plus the
  nuisance priors' precision (:func:`olsbayes.bounds.bayesian_information`) --
  the prior density there, log K! and the Gaussian mass inside the prior's box;
  trust diagnostics on the scene's marginal information.  ``method="nested"``, and
  ``"auto"`` for the K in doubt, integrate by dynesty nested sampling instead.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from .. import measurement
from ..bounds import bayesian_information, bound_covariance, marginal_information
from ..ml.irls import refine_general
from ..model import Model
from ..priors import ScenePrior
from .diagnostics import laplace_trust
from .engine import KWork
from .laplace import LOG_2PI, support_log_mass
from .options import NestedOptions

__all__ = ["noise_work_general", "laplace_work_general", "nested_work_general",
           "general_log_likelihood", "QUADRATURE_POINTS"]

#: Points of the quadrature of one extra parameter over its prior's unit interval.
QUADRATURE_POINTS = 20001


def general_log_likelihood(model: Model, data: np.ndarray, p: int, frames: bool
                           ) -> Callable[[np.ndarray], np.ndarray]:
    """``x (..., P + Q) -> log L (...,)`` of the scene (first ``p``) and the extras."""
    q = measurement.n_extra(model)

    def log_like(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ll = measurement.log_likelihood(model, x[..., :p], data,
                                            extra=x[..., p:] if q else None, frames=frames)
        return np.where(np.isnan(ll), -np.inf, ll)

    return log_like


def _laplace(model: Model, x: np.ndarray, ll: float, prior: ScenePrior, n_frames: int | None,
             k: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Laplace log Z, the full information and the sds at a full point x (P + Q,)."""
    p = model.n_params(k)
    info = bayesian_information(model, x[:p], x[p:] if x.size > p else None, n_frames=n_frames)
    sign, logdet = np.linalg.slogdet(info)
    cov, _, singular = bound_covariance(info)
    sd = np.sqrt(np.where(singular, np.nan, np.clip(np.diag(cov), 0.0, None)))
    if sign <= 0 or not np.isfinite(logdet) or singular.any():
        return math.nan, info, sd
    log_z = (ll + float(prior.log_prob(x)) + 0.5 * x.size * LOG_2PI - 0.5 * logdet
             + prior.log_label_factor + float(support_log_mass(x, sd, prior)))
    return float(log_z), info, sd


def noise_work_general(model: Model, data: np.ndarray, prior: ScenePrior, frames: bool
                       ) -> KWork:
    """K = 0: the evidence of no source (extras integrated)."""
    from scipy.special import logsumexp  # on use: scipy is slow to import
    t0 = time.perf_counter()
    q = len(prior.extra)
    log_like = general_log_likelihood(model, data, 0, frames)
    if q == 0:
        value = float(log_like(np.zeros(0)))
        return KWork(0, value, 0.0, "closed-form", value, np.zeros(0), laplace=value,
                     seconds=time.perf_counter() - t0)
    if q == 1:
        u = (np.arange(QUADRATURE_POINTS) + 0.5) / QUADRATURE_POINTS
        ll = log_like(prior.ppf(u[:, None]))
        value = float(logsumexp(ll) - math.log(QUADRATURE_POINTS))
        return KWork(0, value, 0.0, "quadrature", float(np.max(ll)), np.zeros(0),
                     laplace=math.nan, seconds=time.perf_counter() - t0)
    s = data[None]
    _, _, eta0, _ = measurement.surrogate(model, s, frames)
    out = refine_general(model, s, np.zeros((1, 0)), eta0, frames=frames)
    x = out.extra[0]
    ll = float(log_like(x))
    n_f = data.shape[-2] if frames else None
    value, _, _ = _laplace(model, x, ll, prior, n_f, 0)
    return KWork(0, value, math.nan, "laplace", ll, np.zeros(0), laplace=value,
                 seconds=time.perf_counter() - t0)


def laplace_work_general(model: Model, data: np.ndarray, k: int, fit, prior: ScenePrior,
                         thresholds, frames: bool) -> KWork:
    """Laplace evidence of K sources at the ML fit ``fit`` (an MLResult), with trust reasons."""
    t0 = time.perf_counter()
    params = np.asarray(fit.params, float)
    x = np.concatenate([params, np.asarray(fit.extra, float)])
    ll = float(fit.log_likelihood)
    n_f = data.shape[-2] if frames else None
    log_z, info, _ = _laplace(model, x, ll, prior, n_f, k)
    reasons, stats = laplace_trust(model, params, marginal_information(info, params.size),
                                   thresholds=thresholds)
    if not bool(np.all(fit.converged)):
        reasons = reasons + ("ML optimiser did not meet its stopping rule",)
    if np.isfinite(log_z) and log_z > ll:
        reasons = reasons + ("Laplace exceeds the likelihood maximum (Gaussian wider "
                             "than the prior)",)
    if not np.isfinite(prior.log_prob(x)):
        reasons = reasons + ("ML point outside the prior's support",)
    return KWork(k, log_z, math.nan, "laplace", ll, params, laplace=log_z, reasons=reasons,
                 n_calls=int(np.sum(fit.n_evaluations)),
                 seconds=time.perf_counter() - t0, fit=fit, stats=stats, origin="fit_ml")


def nested_work_general(model: Model, data: np.ndarray, work: KWork, prior: ScenePrior,
                        options: NestedOptions, frames: bool, *,
                        rng: np.random.Generator) -> KWork:
    """Replace a K's evidence by ``options.n_runs`` combined dynesty runs (Laplace kept)."""
    import dataclasses

    from .nested_error import repeated_log_evidence, scaled_maxcall

    log_like = general_log_likelihood(model, data, model.n_params(work.k), frames)
    p = prior.n_params
    live = options.n_live or max(100, 25 * p)
    cap = options.maxcall or scaled_maxcall(p, live, n_sensors=model.n_sensors,
                                            n_runs=options.n_runs)
    out = repeated_log_evidence(lambda z: float(log_like(z)), prior.ppf, p,
                                n_runs=options.n_runs, periodic=prior.periodic_indices,
                                rng=rng, maxcall=cap, n_live=live, dlogz=options.dlogz)
    reasons = work.reasons if out.converged else work.reasons + (
        f"nested sampling stopped at maxcall={cap}",)
    if out.disagree:
        reasons += (f"{len(out.runs)} nested runs disagree by {out.spread:.2f} nats beyond "
                    "their own errors (posterior mass found by some runs only)",)
    return dataclasses.replace(
        work, value=out.log_evidence, error=out.error, method="nested", reasons=reasons,
        n_calls=work.n_calls + out.n_calls, seconds=work.seconds + out.seconds)


def _prior_of(model: Model, data: np.ndarray, priors: object, i_max: float | None,
              frames: bool) -> Callable[[int], ScenePrior]:
    """``K -> ScenePrior`` with the model's extras (default priors, or the user's, checked)."""
    from ..posterior._general import check_prior_extras
    from .scene_priors import prior_factory

    return prior_factory(model, data, priors, i_max, frames=frames,
                         check=lambda p: check_prior_extras(model, p))


def select_general(model: Model, data: object, k_max: int, *, priors: object,
                   log_pk: np.ndarray, i_max: float | None, method: str, options,
                   rng: object, frames: bool):
    """:func:`olsbayes.select.select_k` for models beyond Gaussian noise of known sigma.

    ``k_max``, ``method``, ``options`` and ``log_pk`` (the prior on K) are checked by
    the caller.  BIC/AIC use the maximum log-likelihood with P counting the extras.
    """
    from .._validation import as_rng, flag
    from ..errors import InputError
    from ..ml import fit_ml
    from .criteria import aic, bic
    from .decide import finish, next_escalation

    t0 = time.perf_counter()
    frames = flag("frames", frames)
    data = model.check_data(data, frames=frames)
    if data.ndim != 1 + frames:
        raise InputError(f"data must be one measurement of shape "
                         f"{'(F, N)' if frames else '(N,)'} with N = {model.n_sensors}; "
                         f"got shape {data.shape}")
    prior_of = _prior_of(model, data, priors, i_max, frames)
    scene_priors = {k: prior_of(k) for k in range(1, k_max + 1)}
    one = scene_priors[1] if k_max else _prior_of(model, data, None, i_max, frames)(1)
    scene_priors[0] = ScenePrior(model, 0, one.intensity, location=one.location,
                                 extra=one.extra)  # the extras' priors of every K
    streams = [s.spawn(2) for s in as_rng(rng).spawn(k_max + 1)]
    works = [noise_work_general(model, data, scene_priors[0], frames)]
    for k in range(1, k_max + 1):
        fit = fit_ml(model, data, k, options.ml_method, options=options.ml_options,
                     rng=streams[k][0], warn=False, frames=frames)
        w = laplace_work_general(model, data, k, fit, scene_priors[k],
                                 options.laplace.thresholds, frames)
        if method in ("bic", "aic"):
            p = scene_priors[k].n_params
            n_obs = model.n_sensors * (data.shape[0] if frames else 1)
            crit = bic(w.log_likelihood, p, n_obs) if method == "bic" else aic(
                w.log_likelihood, p)
            w = KWork(k, -0.5 * crit, math.nan, method, w.log_likelihood, w.params, fit=fit,
                      n_calls=w.n_calls, origin="fit_ml")
        elif method == "nested":
            w = nested_work_general(model, data, w, scene_priors[k], options.nested, frames,
                                    rng=streams[k][1])
        works.append(w)
    escalated: dict[int, str] = {}
    while method == "auto" and len(escalated) < options.decision.max_escalations:
        nxt = next_escalation(works, log_pk, options.decision, set(escalated))
        if nxt is None:
            break
        k, escalated[nxt[0]] = nxt
        works[k] = nested_work_general(model, data, works[k], scene_priors[k], options.nested,
                                       frames, rng=streams[k][1])
    return finish(works, log_pk, method, escalated, options.decision, time.perf_counter() - t0)
