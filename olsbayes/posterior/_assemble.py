"""From an emcee chain to the stored posterior: burn-in, thinning, relabelling, InferenceData.

Sources are labelled as in the walkers' starting point (the ML estimate by
default, in canonical order), so the posterior's ``theta[0]`` is the ML table's
source 0 (:mod:`olsbayes.posterior._labels`).  The InferenceData also gets the
posterior predictive readings -- one noisy replicate of the readings per stored
draw, drawn from the same stream as the prior draws, after them.  Its pointwise
log-likelihood (read by model comparison only) is computed on first access
(:mod:`olsbayes.posterior._lazy`), with the same numbers.  These two per-reading
groups hold every stored draw while they fit in :data:`READING_FLOATS` numbers
each, else every s-th stored draw (the posterior's own ``draw`` labels), so that
their memory and time stay bounded whatever the number of sub-sensors.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from ..bounds import bound_covariance
from ..circular import circular_mean
from ..errors import ConvergenceWarning
from ..model import Model
from ..priors import ScenePrior
from . import _general
from ._arviz import to_inference_data
from ._labels import block_index, dominant_permutation, relabel
from ._logpost import LogPosterior
from .audit import at_prior_bound
from .options import SamplerOptions

__all__ = ["assemble", "crlb_covariance", "predictive_draws", "reading_stride",
           "MAX_STORED_DRAWS", "PRIOR_DRAWS", "READING_FLOATS"]

#: Draws kept per walker at most (further thinning beyond this), bounds memory.
MAX_STORED_DRAWS = 5000
#: Independent prior draws stored in the InferenceData ``prior`` group.
PRIOR_DRAWS = 2000
#: Numbers (walkers x draws x sub-sensors) a per-reading group -- the posterior
#: predictive readings, the pointwise log-likelihood -- holds at most before it keeps
#: every s-th draw only: 256 MiB each.  32 walkers x 5000 draws reach it from about
#: 210 sub-sensors; a 1000-ring's run of 1600 draws keeps every 2nd draw there.
READING_FLOATS = 2**25


def reading_stride(n_walkers: int, n_draws: int, n_sensors: int) -> int:
    """Every how many stored draws the per-reading groups keep one (1: all of them).

    The smallest s with ``n_walkers * ceil(n_draws / s) * n_sensors <= READING_FLOATS``
    (or one draw per walker where even that does not fit).
    """
    per_draw = n_walkers * n_sensors
    room = max(1, READING_FLOATS // max(per_draw, 1))
    return max(1, -(-n_draws // room))


def _kept_steps(tau: np.ndarray, n_steps: int, options: SamplerOptions
                ) -> tuple[np.ndarray, int, int]:
    """Indices of the stored steps, the burn-in and the thinning actually used.

    An explicit ``n_burn`` is honoured when the run is longer; otherwise (a run that
    stopped early) the first half is discarded, with a warning.
    """
    n_burn = options.n_burn
    if n_burn is None:
        n_burn = int(np.ceil(5 * np.nanmax(tau))) if np.all(np.isfinite(tau)) else n_steps // 2
        n_burn = min(n_burn, n_steps // 2)
    elif n_burn >= n_steps:
        warnings.warn(f"n_burn={n_burn} is not below the {n_steps} steps the run took (it "
                      f"stopped early, its convergence criteria met): the first half, "
                      f"{n_steps // 2} steps, is discarded instead", ConvergenceWarning,
                      stacklevel=4)
        n_burn = n_steps // 2
    thin = max(options.thin, int(np.ceil((n_steps - n_burn) / MAX_STORED_DRAWS)))
    return np.arange(n_burn, n_steps)[::thin], n_burn, thin


def _point_estimate(x: np.ndarray, prior: ScenePrior) -> np.ndarray:
    """Posterior mean (P,) of draws (W, D, P); circular mean for periodic parameters."""
    estimate = x.reshape(-1, x.shape[-1]).mean(axis=0)
    if prior.periodic.any():
        estimate[prior.periodic] = circular_mean(x[..., prior.periodic].reshape(
            -1, int(prior.periodic.sum())), axis=0)
    return estimate


#: Readings whose noise is drawn at once (a buffer small enough to stay in cache).
_NOISE_BLOCK = 1 << 15


def predictive_draws(model: Model, prior: ScenePrior, x: np.ndarray,
                     gen: np.random.Generator, mu: np.ndarray | None = None) -> np.ndarray:
    """Replicated readings (..., N): the response of every draw x (..., P) plus noise.

    The noise sd is the draw's ``sigma`` when it is inferred, else ``model.sigma``;
    the noise is ``gen.standard_normal`` of shape (..., N), drawn block by block
    of draws (the same stream).  ``mu`` (..., N): the draws' response when the
    caller has it already; the replicas are written into it.
    """
    p_model = model.n_params(prior.n_sources)
    flat = x.reshape(-1, x.shape[-1])
    n = model.n_sensors
    if mu is not None:
        rep = mu.reshape(flat.shape[0], n)
    elif p_model:
        rep = model.response(flat[:, :p_model])
    else:
        rep = np.zeros((flat.shape[0], n))
    sd = flat[:, -1:] if prior.noise is not None else model.sigma
    rows = max(1, _NOISE_BLOCK // n)
    noise = np.empty((min(rows, rep.shape[0]), n))
    for lo in range(0, rep.shape[0], rows):
        part = rep[lo:lo + rows]
        z = noise[:part.shape[0]]
        gen.standard_normal(out=z)
        np.multiply(sd if np.ndim(sd) == 0 else sd[lo:lo + rows], z, out=z)
        np.add(part, z, out=part)  # mu + sd * noise
    return rep.reshape(x.shape[:-1] + (n,))


def assemble(model: Model, data: np.ndarray, logpost: LogPosterior, sampler,
             centre: np.ndarray | None, options: SamplerOptions,
             gen_prior: np.random.Generator, run_attrs: dict | None = None) -> dict:
    """The fields of a :class:`~olsbayes.posterior.PosteriorResult` from a finished sampler.

    All fields but ``converged``, ``elapsed``, ``n_evaluations``, ``seed`` and ``provenance``;
    ``run_attrs`` (provenance) are written into the InferenceData's attributes.
    """
    import emcee

    from .._version import __version__
    from ._lazy import Deferred

    prior = logpost.prior
    chain = sampler.get_chain()  # (steps, W, P) sampler coordinates
    n_steps = chain.shape[0]
    with np.errstate(invalid="ignore"):  # a walker that never moved: NaN tau, not a warning
        tau = np.asarray(sampler.get_autocorr_time(tol=0), dtype=float)
    keep, n_burn, thin = _kept_steps(tau, n_steps, options)
    kept = chain[n_burn::thin]  # chain[keep], a view
    moved = np.any(kept != chain[np.maximum(keep - 1, 0)], axis=-1)
    moved[keep == 0] = True
    z = kept.swapaxes(0, 1)  # (W, D, P)
    lpost = sampler.get_log_prob()[n_burn::thin].T - logpost.jacobian(z)  # density of x, not z
    x = logpost.to_params(z)
    w = prior.n_loc + 1
    periodic_loc = prior.periodic[:w] if prior.n_sources else np.zeros(w, bool)
    switch = 0.0
    if options.relabel_sources:
        x, perms = relabel(x, prior.n_sources, periodic_loc, lpost, anchor=centre)
        perm, switch = dominant_permutation(perms)
        tau = tau[block_index(perm, w, prior.n_params)]  # tau of the relabelled parameters
    estimate = _point_estimate(x, prior)
    general = logpost.general
    n_frames = data.shape[-2] if logpost.frames else None
    crlb_cov = (_general.crlb_covariance(model, prior, estimate, n_frames) if general
                else crlb_covariance(model, prior, estimate))
    acceptance = np.asarray(sampler.acceptance_fraction)
    constants = _constants(model, prior, centre, n_frames, crlb_cov=crlb_cov,
                           estimate=estimate, tau=tau, acceptance_fraction=acceptance)
    stride = reading_stride(x.shape[0], x.shape[1], model.n_sensors)
    attrs = {"inference_library": "emcee", "inference_library_version": emcee.__version__,
             "olsbayes_version": __version__, "kind": model.kind,
             "n_sources": prior.n_sources, "n_burn": n_burn, "thin": thin, "n_steps": n_steps,
             "parameter_names": " ".join(prior.param_names), "reading_stride": stride,
             **{k: v for k, v in (run_attrs or {}).items() if v is not None}}
    prior_draws = prior.sample((1, PRIOR_DRAWS), rng=gen_prior)
    xs = x[:, ::stride]  # the draws of the per-reading groups
    if general:
        observed = _general.statistic(model, data, logpost.frames)
        replicas = _general.predictive(model, prior, xs, gen_prior, n_frames)
        pointwise = logpost.pointwise(xs)
    else:  # the pointwise likelihood (read by model comparison only) when first read
        mu = model.response(xs[..., :logpost.n_model]) if logpost.n_model else None
        pointwise = Deferred(functools.partial(logpost.pointwise, xs),
                             xs.shape[:-1] + (model.n_sensors,))
        observed, replicas = data, predictive_draws(model, prior, xs, gen_prior, mu)
    idata = to_inference_data(
        x, prior.param_names, sample_stats={"lp": lpost, "log_prior": prior.log_prob(x),
                                            "acceptance_rate": moved.T.astype(float)},
        pointwise=pointwise, data=observed, constants=constants,
        attrs=attrs, periodic=prior.periodic, centre=estimate,
        predictive=replicas, prior_draws=prior_draws, reading_stride=stride)
    return dict(idata=idata, model=model, prior=prior, n_sources=prior.n_sources,
                names=tuple(prior.param_names), estimate=estimate, crlb_cov=crlb_cov,
                start=centre, tau=tau, n_steps=n_steps, n_burn=n_burn, thin=thin,
                acceptance_fraction=acceptance, switch_fraction=switch,
                at_bound=at_prior_bound(x, prior) if options.use_likelihood else ())


def _constants(model: Model, prior: ScenePrior, centre: np.ndarray | None,
               n_frames: int | None, **arrays: np.ndarray) -> dict:
    """The InferenceData's constant_data: ``arrays`` plus the array's and the noise's."""
    constants = {"normals": model.array.normals, **arrays}
    if centre is not None:
        constants["start"] = centre
    if model.array.positions is not None:
        constants["positions"] = model.array.positions
    if prior.noise is None and model.noise.is_default:
        constants["sigma"] = np.array(model.sigma)
    if n_frames is not None:
        constants["n_frames"] = np.array(n_frames)
    return constants


def crlb_covariance(model: Model, prior: ScenePrior, x: np.ndarray) -> np.ndarray:
    """CRLB covariance (P, P) at ``x``, with the sigma block sigma^2 / (2 N) if inferred."""
    p_model = model.n_params(prior.n_sources)
    out = np.full((prior.n_params, prior.n_params), 0.0)
    fisher = model.fisher(x[:p_model])
    if prior.noise is not None:
        fisher = fisher * (model.sigma / x[-1]) ** 2
        out[-1, -1] = x[-1] ** 2 / (2 * model.n_sensors)
    out[:p_model, :p_model] = bound_covariance(fisher)[0]
    return out
