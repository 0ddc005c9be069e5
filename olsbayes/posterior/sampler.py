"""Posterior sampling with emcee: a vectorised ensemble seeded at the ML point.

Or one ensemble per mode when the posterior has several
(:mod:`olsbayes.posterior.multimodal`).
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from .._budget import check_memory
from .._provenance import draw_seed, provenance, seed_of
from .._validation import as_rng, file_path, flag, integer
from ..antipodal import antipodal_pairs
from ..errors import (
    AntipodalWarning,
    ConvergenceWarning,
    InputError,
    MultimodalWarning,
    PriorBoundWarning,
)
from ..measurement import is_plain
from ..ml import MLResult, fit_ml
from ..model import Model
from ..priors import ScenePrior, default_priors
from ..resolution import antipodal_doubts
from ._assemble import MAX_STORED_DRAWS, READING_FLOATS, assemble
from ._checkpoint import ChainCheckpoint, problem_key
from ._general import check_prior_extras
from ._logpost import LogPosterior, cut_shift
from ._modal import check_multimodal_start, mode_plan, sample_modes
from ._run import make_sampler, posterior_bar, run_ensemble
from ._start import check_start, initial_walkers, start_coordinates
from .audit import narrower_than_crlb
from .modes import find_modes
from .multimodal import model_point
from .options import SamplerOptions
from .result import PosteriorResult

__all__ = ["sample", "start_coordinates"]


def _check_prior(model: Model, k: int, priors: object, data: np.ndarray,
                 frames: bool = False) -> ScenePrior:
    if priors is None:
        return default_priors(model, k, data=data, frames=frames)
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
    check_prior_extras(model, priors)
    return priors


def _check_options(options: object, n_params: int) -> tuple[SamplerOptions, int]:
    """The options record and the number of walkers (>= 2 P)."""
    if options is None:
        options = SamplerOptions()
    elif not isinstance(options, SamplerOptions):
        raise InputError(f"options must be an olsbayes.posterior.SamplerOptions or None; "
                         f"got {type(options).__name__}")
    n_walkers = max(32, 4 * n_params) if options.n_walkers is None else options.n_walkers
    if n_walkers < 2 * n_params:
        raise InputError(f"n_walkers must be >= 2 * n_params = {2 * n_params}; got {n_walkers}")
    return options, n_walkers


def _check_memory(n_walkers: int, n_params: int, n_sensors: int, steps: int) -> None:
    """Refuse runs whose stored arrays exceed the memory budget, before any allocation.

    emcee allocates the whole chain (steps, W, P) and log-probabilities (steps, W) at
    the start; the result keeps at most MAX_STORED_DRAWS draws per walker of the
    parameters (a few copies while relabelling) and per-reading groups (W, D', N) of at
    most READING_FLOATS numbers (:func:`~._assemble.reading_stride`).
    """
    kept = min(steps, MAX_STORED_DRAWS)
    readings = min(kept * n_sensors, READING_FLOATS // n_walkers + n_sensors)  # per walker
    nbytes = 8.0 * n_walkers * (steps * (n_params + 1) + kept * 3 * n_params + readings)
    check_memory(f"n_walkers={n_walkers} x {steps} steps x {n_params} parameters "
                 f"({n_sensors} readings)", nbytes)


def sample(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    *,
    priors: ScenePrior | None = None,
    start: object = None,
    options: SamplerOptions | None = None,
    rng: np.random.Generator | int | None = None,
    progress: bool = True,
    checkpoint: str | os.PathLike | None = None,
    frames: bool = False,
) -> PosteriorResult:
    """Sample the posterior of ``n_sources`` sources with an emcee ensemble.

    Every argument is checked before any work (in particular before the ML fit
    that seeds the walkers).

    Parameters
    ----------
    model : Model
        Any noise model and nuisance terms: their inferred extras (an unknown
        sigma, background, gains, offsets) are sampled with the sources, after them.
    data : ndarray (N,), or (F, N) with ``frames``
        One vector of readings, or F frames of one scene.
    n_sources : int
        K >= 1.
    priors : ScenePrior, optional
        Default :func:`~olsbayes.priors.default_priors` with ``data`` (a data-based
        intensity bound; pass priors explicitly for evidence work).
    start : None, MLResult, "prior", ndarray (P,) or (n_walkers, P)
        None: walkers start in a ball N(x_ML, CRLB(x_ML)) around the maximum-
        likelihood point from :func:`olsbayes.ml.fit_ml` (capped at the prior
        scale where the bound is singular).  An ``MLResult`` of one fit: the same
        ball around its ``params`` (no second ML fit).  A point (P,): the same ball
        around it.  An ensemble (n_walkers, P): used as is.  "prior": independent
        prior draws (not recommended for K >= 2: such walkers can stay stuck in
        poor local modes far beyond the default step limit).
    options : SamplerOptions, optional
        Number of walkers, run length and stopping rule, burn-in, thinning, moves,
        and whether to use the multimodal sampler (``multimodal``: by default
        chosen automatically when the ML fit or the run shows signs of several
        modes, see :mod:`olsbayes.posterior.multimodal`; one ensemble for frames,
        other noise models or nuisance terms, and with a ``checkpoint``); default
        ``SamplerOptions()``.
    rng : Generator or int, optional
        The same rng gives identical chains.  None: a seed is drawn from the
        system's entropy and recorded (``result.seed``), so the run can be repeated.
    progress : bool
        A status line on stderr while the run lasts (after a few seconds): the
        steps taken, tau and the steps the stopping rule asks for, the last R-hat
        against ``rhat_max``.
    checkpoint : path, optional
        An ``.npz`` file the run writes as it goes (every minute, at its end and
        when interrupted) and, when it exists, continues from: the same call
        again gives the draws an uninterrupted run would have given; its stopping
        settings may differ (a larger ``max_steps`` continues a run that hit its
        limit).  Without ``rng`` the seed recorded in the file is used (a run
        seeded by a Generator records none: its resumed start may differ, the
        stored chain is continued all the same).  A file of
        other readings, model, prior, walkers or moves is refused
        (:mod:`olsbayes.posterior._checkpoint`).
    frames : bool
        ``data`` holds F frames of one static scene (fitted jointly).

    Returns
    -------
    PosteriorResult
        Sources labelled as in the starting point (the ML estimate's canonical
        order by default).  A :class:`~olsbayes.errors.PriorBoundWarning` is issued
        when a posterior piles up at a prior bound (``result.at_bound``).  When the
        multimodal sampler ran, ``result.modes`` lists the modes and their weights,
        and a :class:`~olsbayes.errors.MultimodalWarning` says why it was chosen
        (unless requested).  Four ring sources or more with a pair within one
        sensor spacing of antipodal, or two such pairs
        (:func:`olsbayes.resolution.antipodal_doubts` at the ML start), warn
        :class:`~olsbayes.errors.AntipodalWarning`: intervals of such scenes
        under-covered in simulation whichever sampler ran.
    """
    frames = flag("frames", frames)
    data, k = _check_scene(model, data, n_sources, frames)
    prior = _check_prior(model, k, priors, data, frames)
    options, n_walkers = _check_options(options, prior.n_params)
    _check_memory(n_walkers, prior.n_params, model.n_sensors, options.step_limit)
    start = check_start(model, prior, start, n_walkers)
    check_multimodal_start(options, start)
    single = frames or not is_plain(model) or checkpoint is not None
    if options.multimodal and single:
        raise InputError("SamplerOptions(multimodal=True) samples one vector of readings of the "
                         "Gaussian model without nuisance terms and without a checkpoint; "
                         "use multimodal=None or False here")
    flag("progress", progress)
    ckpt = None
    if checkpoint is not None:
        ckpt = ChainCheckpoint(file_path("checkpoint", checkpoint),
                               problem_key(model, data, prior, n_walkers, options))
        ckpt.check_seed(None if rng is None else seed_of(rng))
        if rng is None and ckpt.seed is not None:
            rng = ckpt.seed
    if rng is None:
        rng = draw_seed()
    seed = seed_of(rng)
    gen_ml, gen_ball, gen_mc, gen_prior = as_rng(rng).spawn(4)
    record = provenance(seed=rng, data=data)
    if start is None and not single:
        with warnings.catch_warnings():  # the posterior reports near-antipodal pairs itself
            warnings.simplefilter("ignore", AntipodalWarning)
            start = fit_ml(model, data, k, rng=gen_ml)
    plan = None if single else mode_plan(model, data, prior, start, options)
    run = _Run(model, data, prior, options, n_walkers, (gen_ball, gen_mc, gen_prior), record,
               bool(progress), (frames, single, ckpt, seed))
    t0 = time.perf_counter()
    if plan is None:
        walkers, centre = initial_walkers(model, data, prior, start, n_walkers, gen_ml, gen_ball,
                                          frames)
        fields, converged, calls = run.one(walkers, centre)
    else:
        centre = _centre(model, prior, data, start)
        fields, converged, calls = run.modes(plan, centre)
    result = _finish(fields, converged, calls, time.perf_counter() - t0, seed, record, options)
    if options.use_likelihood:
        result = _audit(run, result, plan, centre, t0, seed)
    return result


def _centre(model: Model, prior: ScenePrior, data: np.ndarray, start: object) -> np.ndarray:
    """The full start point (P,) of an MLResult or a point start (labels of the result)."""
    if isinstance(start, MLResult):
        return model_point(model, prior, data, np.asarray(start.params, dtype=float))
    return np.asarray(start, dtype=float).copy()


class _Run:
    """The settings of one call of :func:`sample`, and its two ways to sample."""

    def __init__(self, model, data, prior, options, n_walkers, gens, record, progress, how):
        self.model, self.data, self.prior, self.options = model, data, prior, options
        self.n_walkers, self.gens, self.record, self.progress = n_walkers, gens, record, progress
        # frames; one ensemble only (frames, other noise models, a checkpoint); its checkpoint
        self.frames, self.single, self.ckpt, self.seed = how

    def one(self, walkers: np.ndarray, centre: np.ndarray | None) -> tuple[dict, bool, int]:
        """One ensemble from ``walkers`` (W, P): (result fields, converged, calls)."""
        options = self.options
        _, gen_mc, gen_prior = self.gens
        with posterior_bar(self.progress, options) as bar:  # set-up, steps and assembly
            logpost = LogPosterior(self.model, self.data, self.prior,
                                   cut_shift(self.prior, walkers), options.use_likelihood,
                                   self.frames)
            z0 = start_coordinates(logpost, walkers)
            sampler = make_sampler(logpost, self.n_walkers, options, gen_mc)
            converged = run_ensemble(sampler, z0, logpost, options, bar, self.ckpt, self.seed)
            bar.set_postfix_str("assembling the draws")
            fields = assemble(self.model, self.data, logpost, sampler, centre, options,
                              gen_prior, self.record)
        if options.n_steps is not None:
            converged = bool(options.n_steps >= options.tau_multiple * np.max(fields["tau"]))
        return fields, converged, logpost.n_calls

    def modes(self, plan: tuple, centre: np.ndarray) -> tuple[dict, bool, int]:
        """The multimodal sampler over ``plan`` (:func:`~._modal.sample_modes`)."""
        return sample_modes(self.model, self.data, self.prior, plan, centre, self.n_walkers,
                            self.options, self.gens, self.record, self.progress)


def _finish(fields: dict, converged: bool, calls: int, elapsed: float, seed, record,
            options: SamplerOptions) -> PosteriorResult:
    """The result, with the convergence and prior-bound warnings."""
    max_tau = float(np.max(fields["tau"]))
    if options.n_steps is None and not converged:
        warnings.warn(
            f"emcee stopped at max_steps={options.max_steps} before "
            f"{options.tau_multiple:g} autocorrelation times (max tau = {max_tau:.1f} steps) "
            f"with R-hat < {options.rhat_max}: run longer or check the start (a multimodal "
            "posterior?)",
            ConvergenceWarning,
            stacklevel=3,
        )
    if fields["at_bound"]:
        warnings.warn(
            f"the posterior of {', '.join(fields['at_bound'])} piles up at a bound of its "
            "prior: the prior, not the data, limits it; widen the prior (e.g. a larger "
            "i_max) or leave priors=None for bounds derived from the data",
            PriorBoundWarning,
            stacklevel=3,
        )
    return PosteriorResult(converged=converged, elapsed=elapsed, n_evaluations=calls, seed=seed,
                           provenance=record, **fields)


def _audit(run: _Run, result: PosteriorResult, plan, centre, t0: float, seed
           ) -> PosteriorResult:
    """Warn about what the run may have missed; rerun multimodal on a CRLB alarm.

    The automatic choice (``multimodal=None``) reruns with the multimodal sampler
    when the posterior sd is far below the CRLB at high SNR and the mode search
    finds several modes; otherwise the alarm is a ConvergenceWarning.
    """
    options = run.options
    point = None if centre is None else centre[:run.model.n_params(run.prior.n_sources)]
    if plan is None and centre is not None and not run.single:
        alarm = narrower_than_crlb(result)
        if alarm and options.multimodal is None and options.modes.crlb_alarm:
            what = ", ".join(f"{name} {ratio:.2f}x" for name, ratio, _ in alarm)
            modes, lp = find_modes(run.model, run.data, run.prior, point, options.modes)
            if modes.shape[0] > 1:
                plan = (modes, lp, f"posterior sd far below the CRLB ({what})")
                fields, converged, calls = run.modes(plan, centre)
                result = _finish(fields, converged, calls, time.perf_counter() - t0, seed,
                                 run.record, options)
    mirrored = False
    if plan is None:
        _warn_narrow(result)
        if options.multimodal is False and centre is not None and not run.single:
            mirrored = _warn_antipodal(run.model, point, options)
    elif plan[2] != "requested":
        m = result.modes
        warnings.warn(
            f"the multimodal sampler was chosen ({plan[2]}): {m.n_modes} modes, weights "
            f"{np.array2string(m.weight, precision=3)}, each sampled and weighted by its "
            "evidence; see PosteriorResult.modes",
            MultimodalWarning,
            stacklevel=3,
        )
    if not mirrored and centre is not None and not run.single:
        _warn_doubts(run.model, point)
    return result


def _warn_doubts(model: Model, centre: np.ndarray) -> None:
    """AntipodalWarning where sampled intervals were found to under-cover (P_model,).

    The ML start's pairs in :func:`olsbayes.resolution.antipodal_doubts` (four
    sources or more with a pair within one sensor spacing of antipodal, or two such
    pairs): there, in simulation, the posterior intervals of this sampler -- one
    ensemble per mode included -- covered the truth less often than stated at some
    SNR, converged runs among them.
    """
    if antipodal_doubts(model, centre[None])[0]:
        warnings.warn(
            "a pair of sources near antipodal among four or more (or two such pairs): in "
            "simulation, posterior intervals of such scenes covered the truth less often "
            "than stated at some SNR, converged runs included; treat them as approximate "
            "(see olsbayes.antipodal)",
            AntipodalWarning,
            stacklevel=4,
        )


def _warn_antipodal(model: Model, centre: np.ndarray, options: SamplerOptions) -> bool:
    """AntipodalWarning for near-antipodal ring pairs at ``centre`` (P_model,).

    Issued when the multimodal sampler is switched off (``multimodal=False``):
    see :mod:`olsbayes.antipodal` for why such pairs leave mirrored optima.
    Returns whether it warned.
    """
    pairs = antipodal_pairs(model, centre, within=options.modes.antipodal_spacings)
    if pairs:
        what = ", ".join(f"({i}, {j}) {off:+.2f}" for i, j, off in pairs)
        warnings.warn(
            f"source pair(s) {what} sensor spacings from antipodal: mirrored "
            "configurations fit (almost) as well, and one ensemble samples one of them; "
            "leave SamplerOptions(multimodal=None) to sample every mode "
            "(see olsbayes.antipodal)",
            AntipodalWarning,
            stacklevel=4,
        )
    return bool(pairs)


def _warn_narrow(result: PosteriorResult) -> None:
    """ConvergenceWarning when a posterior sd is far below its CRLB at high SNR."""
    narrow = narrower_than_crlb(result)
    if narrow:
        what = ", ".join(f"{name} {ratio:.2f}x (SNR {snr:.0f})" for name, ratio, snr in narrow)
        warnings.warn(
            f"posterior sd far below the CRLB at high SNR: {what}; no unbiased estimate is "
            "this precise, so the walkers have likely not explored the whole posterior "
            "(a multimodal or poorly mixed run): run longer or from another start, and see "
            "PosteriorResult.crlb_check()",
            ConvergenceWarning,
            stacklevel=4,
        )


def _check_scene(model: object, data: object, n_sources: object, frames: bool = False
                 ) -> tuple[np.ndarray, int]:
    """The readings as one checked vector (N,) (frames: (F, N)) and K."""
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    data = model.check_data(data, frames=frames)
    if data.ndim != 1 + frames:
        shape = f"(F, {model.n_sensors})" if frames else f"({model.n_sensors},)"
        raise InputError(f"data must be one measurement of shape {shape}; got {data.shape}")
    return data, integer("n_sources", n_sources, low=1)
