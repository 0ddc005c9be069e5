"""Posterior sampling with emcee: a vectorised ensemble seeded at the ML point."""

from __future__ import annotations

import time
import warnings

import numpy as np

from .._validation import as_rng, finite_array, integer, positive_float
from ..bounds import bound_covariance
from ..circular import circular_mean, largest_gap_cut, wrap_angle
from ..errors import ConvergenceWarning, InputError
from ..model import Model
from ..priors import ScenePrior, default_priors
from ._labels import block_index, dominant_permutation, relabel
from ._logpost import LogPosterior
from ._start import ball_covariance, initial_ensemble, ml_start
from .result import PosteriorResult

__all__ = ["sample"]

#: Draws kept per walker at most (further thinning beyond this), bounds memory.
MAX_STORED_DRAWS = 5000
#: Independent prior draws stored in the InferenceData ``prior`` group.
PRIOR_DRAWS = 2000


def _check_prior(model: Model, k: int, priors: object, data: np.ndarray) -> ScenePrior:
    if priors is None:
        return default_priors(model, k, data=data)
    if not isinstance(priors, ScenePrior):
        raise InputError(
            f"priors must be an olsbayes.priors.ScenePrior (see default_priors); "
            f"got {type(priors).__name__}"
        )
    if priors.kind != model.kind or priors.n_sources != k:
        raise InputError(
            f"priors were built for {priors.n_sources} {priors.kind!r} source(s); the model "
            f"has {model.kind!r} sources and n_sources={k}"
        )
    return priors


def _shift_for(prior: ScenePrior, points: np.ndarray | None) -> np.ndarray:
    """Per-parameter shifts putting the circle's cut in the largest source gap."""
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


def _initial(model, data, prior, start, n_walkers, gen_ml, gen_ball):
    """Walker positions (W, P) in model coordinates and the ball centre (or None)."""
    p = prior.n_params
    if isinstance(start, str):
        if start != "prior":
            raise InputError(
                f"start must be None, an MLResult, 'prior' or an array; got {start!r}")
        return prior.sample(n_walkers, gen_ball), None
    from ..ml import MLResult

    ml_point = None
    if isinstance(start, MLResult):
        ml_point = np.asarray(start.params, dtype=float)
        if ml_point.shape != (model.n_params(prior.n_sources),):
            raise InputError(
                f"start: the MLResult must hold one fit of {prior.n_sources} source(s), "
                f"params of shape ({model.n_params(prior.n_sources)},); got {ml_point.shape}"
            )
    elif start is None:
        ml_point = ml_start(model, data, prior.n_sources, gen_ml)
    if ml_point is not None:
        centre = ml_point
        if prior.noise is not None:
            resid = data - model.response(centre)
            centre = np.append(centre, max(float(np.sqrt(np.mean(resid**2))), 1e-300))
        centre = np.clip(centre, prior.lower, prior.upper)
    else:
        arr = finite_array("start", start, ndim=(1, 2), last=p)
        if arr.ndim == 2:
            if arr.shape[0] != n_walkers:
                raise InputError(
                    f"start ensemble must have shape ({n_walkers}, {p}) (n_walkers, n_params); "
                    f"got {arr.shape}"
                )
            bad = ~prior.contains(arr)
            if bad.any():
                raise InputError(
                    f"start: {int(bad.sum())} walker(s) lie outside the prior support "
                    f"(lower {prior.lower}, upper {prior.upper})"
                )
            return arr.copy(), None
        centre = arr.copy()
    if not prior.contains(centre):
        raise InputError(
            f"start {np.array2string(centre, precision=4)} lies outside the prior support "
            f"(lower {prior.lower}, upper {prior.upper})"
        )
    cov = ball_covariance(model, prior, centre)
    return initial_ensemble(centre, cov, n_walkers, prior.contains, gen_ball), centre


def _moves(moves: object):
    import emcee

    if isinstance(moves, str):
        if moves == "de":
            return emcee.moves.DEMove()
        if moves == "de-snooker":
            return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
        if moves == "stretch":
            return emcee.moves.StretchMove()
        raise InputError(
            f"moves must be 'de', 'de-snooker', 'stretch' or emcee moves; got {moves!r}")
    return moves


def _seed_emcee(sampler, gen: np.random.Generator) -> None:
    seed = int(gen.integers(2**32))
    sampler.random_state = np.random.RandomState(seed).get_state()


def _run(sampler, z0, max_steps, check_every, tau_multiple, progress, rhat_check):
    """Run until n >= tau_multiple * tau (tau stable to 10%) and R-hat holds, or max_steps.

    R-hat is costlier than tau, so once the tau criterion holds it is checked at
    steps growing by 25% at least.
    """
    import emcee

    old = np.inf
    next_rhat = 0
    for _ in sampler.sample(emcee.State(z0), iterations=max_steps, progress=progress):
        it = sampler.iteration
        if check_every is None or it % check_every:
            continue
        tau = sampler.get_autocorr_time(tol=0)
        tmax = float(np.max(tau))
        stable = abs(old - tmax) < 0.1 * tmax
        old = tmax
        if np.isfinite(tmax) and it >= tau_multiple * tmax and stable and it >= next_rhat:
            if rhat_check(tmax):
                return True
            next_rhat = int(1.25 * it)
    return False


def _rhat_checker(sampler, logpost, prior, rhat_max):
    """Closure: True when the post-burn-in draws have max R-hat < rhat_max.

    The draws checked are those ``_assemble`` keeps (same burn-in), so a
    converged result reports R-hat < rhat_max.  Raw draws are tried first;
    they are relabelled only if they fail and K > 1.
    """
    from ._arviz import rhat_array

    def check(tmax: float) -> bool:
        if rhat_max is None:
            return True
        chain = sampler.get_chain()
        burn = min(int(np.ceil(5 * tmax)), chain.shape[0] // 2)
        step = 1  # exactly the draws that will be stored (thin=1), so the verdict carries over
        x = logpost.to_params(chain[burn::step].swapaxes(0, 1))
        if _rhat_max(x, prior, rhat_array) < rhat_max:
            return True
        if prior.n_sources < 2:
            return False
        z = chain[burn::step].swapaxes(0, 1)
        lpost = sampler.get_log_prob()[burn::step].T - logpost.jacobian(z)
        x, perms = relabel(x, prior.n_sources, prior.periodic[: prior.n_loc + 1], lpost)
        if np.all(perms == np.arange(prior.n_sources)):
            return False  # nothing relabelled: the same draws that just failed
        return _rhat_max(x, prior, rhat_array) < rhat_max

    return check


def _rhat_max(x: np.ndarray, prior: ScenePrior, rhat_array) -> float:
    if prior.periodic.any():
        per = prior.periodic
        centre = circular_mean(x[..., per].reshape(-1, int(per.sum())), axis=0)
        x = x.copy()
        x[..., per] = centre + wrap_angle(x[..., per] - centre)
    return float(np.max(rhat_array(x)))


def sample(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    priors: ScenePrior | None = None,
    start: np.ndarray | str | None = None,
    n_walkers: int | None = None,
    rng: np.random.Generator | int | None = None,
    progress: bool = True,
    *,
    vectorize: bool = True,
    max_steps: int = 20000,
    n_steps: int | None = None,
    tau_multiple: float = 50.0,
    rhat_max: float | None = 1.01,
    check_every: int = 100,
    burn: int | None = None,
    thin: int = 1,
    use_likelihood: bool = True,
    moves: object = "de",
    relabel_sources: bool = True,
) -> PosteriorResult:
    """Sample the posterior of ``n_sources`` sources with an emcee ensemble.

    Parameters
    ----------
    model : Model
    data : ndarray (N,)
        One vector of readings.
    n_sources : int
        K >= 1.
    priors : ScenePrior, optional
        Default :func:`~olsbayes.priors.default_priors` with ``data`` (a data-based
        intensity bound; pass priors explicitly for evidence work).
    start : None, MLResult, "prior", ndarray (P,) or (n_walkers, P)
        None: walkers start in a ball N(x_ML, CRLB(x_ML)) around the maximum-
        likelihood point from :func:`olsbayes.ml.fit_ml` (capped at the prior
        scale where the bound is singular).  An ``MLResult`` of one fit: the same
        ball around its ``params`` (no second ML fit).  A point (P,): the same ball around it.
        An ensemble (n_walkers, P): used as is.  "prior": independent prior draws
        (not recommended for K >= 2: such walkers can stay stuck for > 2e4 steps).
    n_walkers : int, optional
        Default ``max(32, 4 P)``; at least ``2 P``.
    rng : Generator or int, optional
        The same rng gives identical chains.
    progress : bool
        Show emcee's progress bar.
    vectorize : bool
        One log-posterior call per ensemble step (True) or per walker (False).
    max_steps : int
        Step limit; if reached first, a :class:`ConvergenceWarning` is issued.
    n_steps : int, optional
        Run exactly this many steps instead (no early stop, no warning;
        ``converged`` still reports whether the tau criterion holds).
    tau_multiple : float
        Run until ``steps >= tau_multiple * max(tau)`` with tau the integrated
        autocorrelation time, checked every ``check_every`` steps.
    rhat_max : float or None
        Also require the rank-normalised split R-hat of the relabelled draws
        (walkers as chains) below this; None drops the requirement.
    burn : int, optional
        Steps discarded; default ``ceil(5 max(tau))`` (at most half the chain).
    thin : int
        Keep every ``thin``-th step (more if needed to keep <= 5000 draws/walker).
    use_likelihood : bool
        False samples the prior (a check of the sampler itself).
    moves : "de", "de-snooker", "stretch" or emcee moves
        "de" (default): emcee's differential-evolution ``DEMove``, whose
        autocorrelation time on these posteriors is about a quarter of the
        affine-invariant ``"stretch"`` move's; "de-snooker": the mixture
        ``DEMove`` 0.8 + ``DESnookerMove`` 0.2 (emcee's suggestion for
        multimodal targets; its snooker step is a Python loop over walkers).
    relabel_sources : bool
        Fix the labels of exchangeable sources (default).  False keeps the raw,
        exchangeable draws (e.g. to check them against the prior).

    Returns
    -------
    PosteriorResult
    """
    import emcee

    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    data = model.check_data(data)
    if data.ndim != 1:
        raise InputError(f"data must be one vector of shape ({model.n_sensors},); got {data.shape}")
    k = integer("n_sources", n_sources, low=1)
    prior = _check_prior(model, k, priors, data)
    p = prior.n_params
    n_walkers = max(32, 4 * p) if n_walkers is None else integer("n_walkers", n_walkers)
    if n_walkers < 2 * p:
        raise InputError(f"n_walkers must be >= 2 * n_params = {2 * p}; got {n_walkers}")
    max_steps = integer("max_steps", max_steps, low=1)
    fixed = n_steps is not None
    if fixed:
        max_steps = integer("n_steps", n_steps, low=1)
    check_every = integer("check_every", check_every, low=1)
    thin = integer("thin", thin, low=1)
    tau_multiple = positive_float("tau_multiple", tau_multiple)
    gen_ml, gen_ball, gen_mc, gen_prior = as_rng(rng).spawn(4)

    walkers, centre = _initial(model, data, prior, start, n_walkers, gen_ml, gen_ball)
    logpost = LogPosterior(model, data, prior, _shift_for(prior, walkers), use_likelihood)
    z0 = logpost.to_sampler(walkers)
    if not np.all(np.isfinite(logpost(z0))):
        raise InputError("start: some walkers have zero posterior density (outside the prior?)")
    from emcee.ensemble import walkers_independent

    if not walkers_independent(z0):
        raise InputError(
            "start: the walkers are not linearly independent (e.g. repeated rows or a "
            "parameter with one value); spread them out or give a single start point"
        )
    fn = logpost if vectorize else (lambda z: float(logpost(z)))
    sampler = emcee.EnsembleSampler(n_walkers, p, fn, vectorize=vectorize,
                                    moves=_moves(moves))
    _seed_emcee(sampler, gen_mc)
    t0 = time.perf_counter()
    if rhat_max is not None:
        rhat_max = positive_float("rhat_max", rhat_max)
    rhat_check = _rhat_checker(sampler, logpost, prior, rhat_max)
    converged = _run(sampler, z0, max_steps, None if fixed else check_every, tau_multiple,
                     progress, rhat_check)
    elapsed = time.perf_counter() - t0
    result = _assemble(model, data, prior, logpost, sampler, centre, burn, thin,
                       relabel_sources, gen_prior)
    if fixed:
        converged = bool(max_steps >= tau_multiple * np.max(result["tau"]))
    elif not converged:
        warnings.warn(
            f"emcee stopped at max_steps={max_steps} before {tau_multiple:g} autocorrelation "
            f"times (max tau = {np.max(result['tau']):.1f} steps) with R-hat < {rhat_max}: "
            "run longer or check the start (a multimodal posterior?)",
            ConvergenceWarning,
            stacklevel=2,
        )
    return PosteriorResult(converged=converged, elapsed=elapsed,
                           n_evaluations=logpost.n_calls, **result)


def _assemble(model, data, prior, logpost, sampler, centre, burn, thin, relabel_sources,
              gen_prior) -> dict:
    """Burn-in, thinning, relabelling, and the InferenceData."""
    from ._arviz import to_inference_data

    chain = sampler.get_chain()  # (steps, W, P) sampler coordinates
    n_steps = chain.shape[0]
    tau = np.asarray(sampler.get_autocorr_time(tol=0), dtype=float)
    if burn is None:
        burn = int(np.ceil(5 * np.nanmax(tau))) if np.all(np.isfinite(tau)) else n_steps // 2
    burn = integer("burn", burn, low=0)
    burn = min(burn, n_steps // 2)
    thin = max(thin, int(np.ceil((n_steps - burn) / MAX_STORED_DRAWS)))
    keep = np.arange(burn, n_steps)[::thin]
    moved = np.any(chain[keep] != chain[np.maximum(keep - 1, 0)], axis=-1)
    moved[keep == 0] = True
    z = chain[keep].swapaxes(0, 1)  # (W, D, P)
    lpost = sampler.get_log_prob()[keep].T - logpost.jacobian(z)  # density of x, not z
    x = logpost.to_params(z)
    w = prior.n_loc + 1
    periodic_loc = prior.periodic[:w] if prior.n_sources else np.zeros(w, bool)
    switch = 0.0
    if relabel_sources:
        x, perms = relabel(x, prior.n_sources, periodic_loc, lpost)
        perm, switch = dominant_permutation(perms)
        tau = tau[block_index(perm, w, prior.n_params)]  # tau of the relabelled parameters
    estimate = x.reshape(-1, x.shape[-1]).mean(axis=0)
    if prior.periodic.any():
        estimate[prior.periodic] = circular_mean(x[..., prior.periodic].reshape(
            -1, int(prior.periodic.sum())), axis=0)
    crlb_cov = _crlb_cov(model, prior, estimate)
    constants = {"normals": model.array.normals, "crlb_cov": crlb_cov, "estimate": estimate}
    if model.array.positions is not None:
        constants["positions"] = model.array.positions
    if prior.noise is None:
        constants["sigma"] = np.array(model.sigma)
    import emcee

    attrs = {"sampler": "emcee", "emcee_version": emcee.__version__, "kind": model.kind,
             "n_sources": prior.n_sources, "burn": burn, "thin": thin, "n_steps": n_steps,
             "parameter_names": " ".join(prior.param_names)}
    idata = to_inference_data(
        x, prior.param_names, log_posterior=lpost, log_prior=prior.log_prob(x),
        accepted=moved.T, pointwise=logpost.pointwise(x), data=data, constants=constants,
        attrs=attrs, prior_draws=prior.sample((1, PRIOR_DRAWS), gen_prior))
    return dict(idata=idata, model=model, prior=prior, n_sources=prior.n_sources,
                names=tuple(prior.param_names), estimate=estimate, crlb_cov=crlb_cov,
                start=centre, tau=tau, n_steps=n_steps, burn=burn, thin=thin,
                acceptance_fraction=np.asarray(sampler.acceptance_fraction),
                switch_fraction=switch)


def _crlb_cov(model: Model, prior: ScenePrior, x: np.ndarray) -> np.ndarray:
    """CRLB covariance (P, P) at ``x``, with the sigma block sigma^2 / (2 N) if inferred."""
    p_model = model.n_params(prior.n_sources)
    out = np.full((prior.n_params, prior.n_params), 0.0)
    fisher = model.fisher(x[:p_model])
    if prior.noise is not None:
        fisher = fisher * (model.sigma / x[-1]) ** 2
        out[-1, -1] = x[-1] ** 2 / (2 * model.n_sensors)
    out[:p_model, :p_model] = bound_covariance(fisher)[0]
    return out
