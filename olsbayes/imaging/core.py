"""``image``: intensities of sources at known directions, with their posterior.

With the directions fixed, Eq. 1 is linear, ``data = A I + noise``, with
``A = design_matrix(model, directions)`` of shape (N, K).  :func:`image`
validates every input, analyses the design (rank, conditioning, null space)
and dispatches on the prior: the Gaussian posterior in closed form; for the
others, the mode of the bounded (nonnegative) least squares, and from it the
MAP search of the two-level prior, the mode alone (``n_samples=0``) or a
sampler -- Gibbs or exact HMC -- started around it.

A box prior given without ``i_max`` gets the bound derived from the readings
(:func:`~olsbayes.imaging.priors.data_bound`).  Whatever the bound, a posterior
that piles up at it -- the credible interval reaching ``i_max``, or the mode on
it -- is reported in ``ImageResult.at_bound`` and warned about
(:class:`~olsbayes.errors.PriorBoundWarning`): the bound, not the data, then
sets the estimate.  Chains whose largest split R-hat exceeds
``ImageOptions.rhat_max`` (1.01, the posterior sampler's threshold) are warned
about (:class:`~olsbayes.errors.ConvergenceWarning`).

Without ``n_samples`` the box priors' Gibbs chains (with exact-HMC moves of the
loose intensities, :mod:`olsbayes.imaging.block`) sample until every intensity
has rank-normalised split R-hat <= ``rhat_max`` and bulk and tail ESS >=
``ess_min`` (:mod:`olsbayes.imaging.chains`); a run that reaches
``max_samples`` first warns :class:`~olsbayes.errors.ConvergenceWarning`.
"""

from __future__ import annotations

import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from .._progress import progress_bar
from .._validation import as_rng, finite_array, flag
from ..errors import ConvergenceWarning, InputError, NullSpaceWarning, PriorBoundWarning
from ..model import Model
from .binary import sparse_relaxation, two_level_map
from .chains import ConvergenceRule, RunLength, box_gibbs
from .design import Design, analyse_design, check_directions, design_matrix
from .gaussian import gaussian_posterior
from .neighbours import neighbour_groups, neighbour_pairs
from .options import ImageOptions
from .priors import Bounded, Gaussian, ImagingPrior, Sparse, TwoLevel, as_prior, with_data_bound
from .result import ImageResult, hpd_interval, split_rhat
from .sparse import SweepMoves, gibbs_intensities
from .truncated import Ridge, sample_truncated_gaussian
from .window import window_moves

__all__ = ["image"]


def image(
    model: Model,
    data: np.ndarray,
    directions: np.ndarray,
    prior: ImagingPrior | str = "bounded",
    *,
    options: ImageOptions | None = None,
    rng: np.random.Generator | int | None = None,
    progress: bool = True,
) -> ImageResult:
    """Posterior of the intensities of sources at known directions.

    Parameters
    ----------
    model : Model
        Array, noise sd (``model.sigma``) and sensitivity law.
    data : array_like, shape (N,)
        One set of readings.
    directions : array_like, shape (K, d) (or (K,) for a ring)
        Known source locations: ring angles, sphere (longitude, latitude) in
        rad, or plate positions.
    prior : Gaussian, NonNegative, Bounded, Sparse, TwoLevel or str
        The intensity prior (:mod:`olsbayes.imaging.priors`), or its name in
        ``PRIORS`` for its default settings (``"bounded"``: uniform on
        ``[0, i_max]`` with ``i_max`` derived from the readings; ``"two-level"``
        has no default, give ``TwoLevel(i_max=...)``).
    options : ImageOptions, optional
        Sampler and search settings; every field set must be one the prior
        uses (:mod:`olsbayes.imaging.options`).
    rng : Generator or seed, optional
        Random stream of the samplers and of the two-level restarts.
    progress : bool
        A progress bar on stderr while a sampler or the two-level search runs
        (shown after a few seconds).

    Returns
    -------
    ImageResult
        ``sampler`` names the path taken: ``"closed-form"`` (Gaussian),
        ``"gibbs"``, ``"hmc"``, ``"mode-only"`` (``n_samples=0``) or
        ``"map-search"`` (TwoLevel).

    Raises
    ------
    InputError
        Before any work: bad model, data length or directions (empty, wrong
        shape, latitude outside [-pi/2, pi/2], unseen by every sub-sensor), an
        unknown prior, ``options`` not an ImageOptions, an option the prior
        does not use, a reference of the wrong length.
    """
    prior = as_prior(prior)
    opts = _as_options(options).resolve(prior)
    loc = check_directions(model, directions)
    y = _readings(model, data)
    if opts.reference is not None and len(opts.reference) != loc.shape[0]:
        raise InputError(f"reference must have shape ({loc.shape[0]},) (one intensity per "
                         f"direction); got ({len(opts.reference)},)")
    flag("progress", progress)
    gen = as_rng(rng)
    # The matrices here are small (K <= a few hundred): BLAS threads only add
    # synchronisation, and on a busy machine oversubscription; one thread makes
    # the cost independent of the BLAS thread setting.
    with threadpool_limits(limits=1, user_api="blas"):
        return _image(model, loc, y, prior, opts, gen, bool(progress))


def _image(model: Model, loc: np.ndarray, y: np.ndarray, prior: ImagingPrior,
           opts: ImageOptions, gen: np.random.Generator, progress: bool) -> ImageResult:
    """:func:`image` on checked inputs."""
    from scipy.optimize import lsq_linear  # on use: scipy is slow to import
    a = design_matrix(model, loc)
    derived = isinstance(prior, Bounded) and prior.i_max is None  # a bound from the readings
    prior = with_data_bound(prior, a, y, model.sigma)
    design = analyse_design(a, loc, model.sigma, prior.scale)
    _warn_null_space(design, opts.null_warn)
    if isinstance(prior, Gaussian):
        return _gaussian(a, y, model.sigma, design, prior, opts.level)
    mode = lsq_linear(a, y, bounds=(0.0, prior.upper), method="bvls").x
    if isinstance(prior, TwoLevel):
        return _two_level(model, loc, a, y, mode, design, prior, opts, gen, progress)
    if opts.n_samples == 0:
        nan = np.full(mode.shape[0], np.nan)
        hi = prior.upper
        at = _warn_at_bound(mode >= hi * (1 - 1e-9), hi, "posterior mode", 3) \
            if np.isfinite(hi) else None
        return ImageResult(prior=prior.name, directions=design.directions, mean=mode, mode=mode,
                           sd=nan, lower=nan, upper=nan, level=opts.level, design=design,
                           rhat=float("nan"), sampler="mode-only", i_max=_i_max(prior),
                           at_bound=at)
    scale = min(prior.scale, _typical(mode)) if derived else prior.scale
    return _sampled(model, loc, a, y, mode, design, prior, scale, opts, gen, progress)


def _i_max(prior: ImagingPrior) -> float | None:
    return float(prior.upper) if np.isfinite(getattr(prior, "upper", np.inf)) else None


def _warn_at_bound(at: np.ndarray, hi: float, what: str, stacklevel: int) -> np.ndarray:
    """Warn PriorBoundWarning when ``at`` (K,) flags directions limited by the bound."""
    at = np.asarray(at, dtype=bool)
    if at.any():
        idx = np.flatnonzero(at)
        shown = ", ".join(map(str, idx[:8])) + (" ..." if idx.size > 8 else "")
        warnings.warn(
            f"the {what} of {idx.size} intensit{'y' if idx.size == 1 else 'ies'} "
            f"(direction {shown}) reaches the prior's upper bound i_max = {hi:.4g}: the "
            "bound, not the data, limits them; raise i_max (or leave it unset to derive "
            "it from the readings)",
            PriorBoundWarning,
            stacklevel=stacklevel,
        )
    return at


def _as_options(options: object) -> ImageOptions:
    if options is None:
        return ImageOptions()
    if not isinstance(options, ImageOptions):
        raise InputError("options must be an olsbayes.imaging.ImageOptions or None; got "
                         f"{type(options).__name__}")
    return options


def _readings(model: Model, data: object) -> np.ndarray:
    y = finite_array("data", data, ndim=1)
    if y.shape[0] != model.n_sensors:
        raise InputError(
            f"data must have length {model.n_sensors} (one reading per sub-sensor); "
            f"got {y.shape[0]}"
        )
    return y


def _warn_null_space(design: Design, null_warn: float) -> None:
    """Warn when the readings leave too many intensity combinations to the prior.

    A combination (right singular vector of the design, singular value s) is
    pinned when its noise sd ``sigma / s`` is below the prior's scale
    (:attr:`Design.effective_rank`); the others -- the exact null space among
    them -- have the prior's intervals, which cover a fixed scene more often
    than stated (three or four ring sources half or one sensor spacing apart on
    the calibration map: 90 % coverage 0.94-1.00).
    """
    k = design.matrix.shape[1]
    unpinned = k - design.effective_rank
    if unpinned > null_warn * k:
        warnings.warn(
            f"the readings pin {design.effective_rank} of {k} intensity combinations to "
            f"better than the prior's scale; the other {unpinned} ({design.nullity} of them "
            f"invisible: design rank {design.rank}) are set by the prior, and so are their "
            "intervals (see result.design.singular_values and result.design.null_space)",
            NullSpaceWarning,
            stacklevel=4,
        )


def _gaussian(a, y, sigma, design, prior, level):
    from scipy.special import ndtri  # on use: scipy is slow to import
    k = a.shape[1]
    post = gaussian_posterior(a, y, sigma, np.full(k, prior.mean), np.full(k, prior.sd))
    z = ndtri(0.5 + level / 2)
    sd = post.sd
    return ImageResult(
        prior=prior.name, directions=design.directions, mean=post.mean, mode=post.mean, sd=sd,
        lower=post.mean - z * sd, upper=post.mean + z * sd, level=level, design=design,
        log_evidence=post.log_evidence,
    )


def _two_level(model, loc, a, y, mode, design, prior, opts, gen, progress):
    """Best local optimum of the MAP search from the rounded mode, L1 relaxation and restarts."""
    i_max, ref = prior.i_max, opts.reference
    ref = None if ref is None else np.asarray(ref, dtype=float)
    groups = neighbour_groups(model, loc, 2 * opts.neighbours) if opts.neighbours else None
    best = None
    relaxed = sparse_relaxation(a, y, model.sigma, i_max)
    starts = [mode, relaxed] + [
        i_max * (gen.random(relaxed.shape[0]) < relaxed / i_max) for _ in range(opts.restarts)
    ]
    with progress_bar(enabled=progress, desc="two-level MAP search", unit=" starts",
                      total=len(starts)) as bar:
        for start in starts:
            run = two_level_map(a, y, model.sigma, i_max, start, p_bright=prior.p_bright,
                                groups=groups, reference=ref)
            if best is None or run.log_posterior > best.log_posterior:
                best = run
            bar.update(1)
    nan = np.full(mode.shape[0], np.nan)
    return ImageResult(prior=prior.name, directions=design.directions, mean=best.x,
                       mode=best.x, sd=nan, lower=nan, upper=nan, level=opts.level,
                       design=design, rhat=float("nan"), sampler="map-search", search=best,
                       i_max=float(i_max))


def _sampled(model, loc, a, y, mode, design, prior, scale, opts, gen, progress):
    """Draws of the box / spike-and-slab posterior from chains started around the mode.

    ``scale`` sizes the starts' jitter and the Gibbs chains' block moves: the
    prior's scale, or for a bound derived from the readings the typical
    intensity of the mode (:func:`_typical`).  Exact HMC keeps the prior's
    scale: it decides there whether the design needs a ridge at all.
    """
    hi, sigma = prior.upper, model.sigma
    x0 = _starts(mode, opts.n_chains, hi, scale, gen)
    acc, run = 1.0, None
    total = None if opts.n_samples is None else opts.n_burn + opts.n_samples
    with progress_bar(enabled=progress, desc=f"imaging ({opts.sampler}, {opts.n_chains} chains)",
                      unit=" sweeps", total=total) as bar:
        if isinstance(prior, Sparse):
            draws = _sparse_gibbs(model, loc, a, y, x0, prior, opts, gen, bar.update)
        elif opts.sampler == "gibbs":
            run = _box_gibbs(model, loc, a, y, x0, hi, scale, opts, gen, bar)
            draws, acc = run.samples, run.acceptance
        else:
            draws, acc = _hmc(a, y, sigma, hi, prior.scale, x0, opts.n_samples, opts.n_burn, gen,
                              design, bar.update)
    if run is not None and run.converged is False:
        d = run.diagnostics
        warnings.warn(
            f"the gibbs chains stopped at max_samples = {opts.max_samples} draws per chain "
            f"before converging: R-hat {d['rhat']:.3g} (target <= {opts.rhat_max:g}), ESS bulk "
            f"{d['ess_bulk']:.0f} and tail {d['ess_tail']:.0f} (target >= {opts.ess_min:g}); "
            "raise max_samples and treat sd and intervals with care",
            ConvergenceWarning, stacklevel=4)
    return _from_draws(prior.name, draws, mode, design, opts, hi, acc,
                       warn_rhat=run is None or run.diagnostics is None)


def _sparse_gibbs(model, loc, a, y, x0, prior, opts, gen, step):
    x0 = np.where(x0 < 0.1 * prior.i_max, 0.0, x0)  # dim sources of the jittered mode: spike
    run = gibbs_intensities(a, y, model.sigma, prior.upper, x0, opts.n_samples, rng=gen,
                            n_burn=opts.n_burn, spike=prior.weight_prior, step=step,
                            moves=SweepMoves(pairs=neighbour_pairs(model, loc, opts.neighbours)))
    return run.samples


def _box_gibbs(model, loc, a, y, x0, hi, scale, opts, gen, bar):
    windows = None
    if opts.window and a.shape[1] > 1:
        windows = window_moves(a, neighbour_groups(model, loc, opts.window), model.sigma)
    rule = None if opts.n_samples is not None else ConvergenceRule(
        opts.rhat_max, opts.ess_min, opts.max_samples)
    moves = SweepMoves(pairs=neighbour_pairs(model, loc, opts.neighbours), windows=windows)
    return box_gibbs(a, y, model.sigma, hi, x0, rng=gen,
                     length=RunLength(opts.n_burn, opts.n_samples, rule), moves=moves,
                     block=opts.block * scale, scale=scale, bar=bar)


def _typical(mode):
    """Typical intensity for sampling under a bound derived from the readings.

    That bound (:func:`~olsbayes.imaging.priors.data_bound`) is a loose ceiling,
    twice the largest intensity any direction's readings allow: sized by it, the
    starts' jitter lands far out along the design's null directions and the
    block surrogate (:mod:`olsbayes.imaging.chains`) is nearly flat across the
    box, so its trajectories cross the whole box.  The largest intensity of the
    bounded least-squares mode is on the scale the data support (an all-zero
    mode gives inf: the bound's own scale is kept).
    """
    top = float(np.max(mode, initial=0.0))
    return top if top > 0 else np.inf


def _starts(mode, n_chains, hi, scale, gen):
    """Chains start dispersed around the bounded least-squares mode, inside the box."""
    jitter = 0.05 * scale * gen.standard_normal((n_chains, mode.shape[0]))
    x0 = np.abs(mode + jitter)
    return np.minimum(x0, hi - 1e-6 * scale) if np.isfinite(hi) else x0


def _hmc(a, y, sigma, hi, scale, x0, n_samples, n_burn, gen, design, step):
    """Exact HMC; a ridge surrogate (then Metropolis-corrected) where A^T A is near singular."""
    q = a.T @ a / sigma**2
    b = a.T @ y / sigma**2
    k = q.shape[0]
    full = design.nullity == 0 and design.singular_values[-1] / sigma > 1e-3 / scale
    ridge = None if full else Ridge(1.0 / scale**2, np.full(k, 0.5 * scale))
    run = sample_truncated_gaussian(q, b, np.zeros(k), np.full(k, hi), x0, n_samples, rng=gen,
                                    n_burn=n_burn, ridge=ridge, step=step)
    return run.samples, run.acceptance


def _from_draws(prior, draws, mode, design, opts, hi, acc, warn_rhat=True):
    flat = draws.reshape(-1, draws.shape[-1])
    k = flat.shape[1]
    level, used = opts.level, opts.sampler
    lo_b, hi_b = np.zeros(k), np.full(k, hi)
    lower, upper = hpd_interval(flat, level, lo_b, hi_b)
    rhat = float(np.nanmax(split_rhat(draws))) if draws.shape[0] > 1 else float("nan")
    if warn_rhat and rhat > opts.rhat_max:
        warnings.warn(
            f"the {used} chains have not mixed: largest split R-hat {rhat:.3g} > "
            f"{opts.rhat_max:g}; increase n_samples/n_burn and treat sd and intervals with care",
            ConvergenceWarning,
            stacklevel=5,
        )
    at = None
    if np.isfinite(hi):
        at = _warn_at_bound(upper >= hi, hi, f"{level:.0%} credible interval", 5)
    p_bright = np.mean(flat > 0, axis=0) if prior == "sparse" else None
    return ImageResult(
        prior=prior, directions=design.directions, mean=flat.mean(axis=0),
        mode=np.median(flat, axis=0) if prior == "sparse" else mode,
        sd=flat.std(axis=0, ddof=1), lower=lower, upper=upper, level=level, design=design,
        samples=draws, p_bright=p_bright, rhat=rhat, acceptance=acc, sampler=used,
        i_max=float(hi) if np.isfinite(hi) else None, at_bound=at,
    )
