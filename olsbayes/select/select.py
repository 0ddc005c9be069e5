"""select_k: the posterior over the number of sources K = 0..K_max.

Pipeline.  K = 0 (noise only) has a closed-form evidence.  Every K >= 1 gets an
ML fit (non-negative intensities: unconstrained fits let BIC/AIC pick a spurious
extra source on 5-8 % of three-source scenes) and its Laplace evidence with
trust diagnostics.  Where Laplace is not to be trusted or undefined (an extra
source at intensity 0 with a free location, a singular Fisher matrix, a weak or
close source) the evidence is computed instead by importance sampling over the
source locations with the intensities integrated analytically
(:mod:`olsbayes.select.mixture`); Laplace is kept where it is trusted (within 0.3
nats of nested sampling there).  ``method="auto"`` then recomputes only the
competing K whose Laplace value is not to be trusted (whatever replaced it), or
whose comparison with the best K is not decisive (at most ``max_escalations`` K,
most probable first; :mod:`olsbayes.select.decide`): by quadrature where it is
exact (K <= 2 ring sources, uniform directions, box intensity priors;
:mod:`olsbayes.select.quadrature`), else by nested sampling.
Finally p(K | data) is proportional to Z_K p(K), and the chosen K is the
*smallest* K within ``tie`` nats of the most probable one: when the data barely
prefer more sources, the simpler scene is reported (and a note says so).
"""

from __future__ import annotations

import time

import numpy as np

from .._budget import check_memory
from .._progress import progress_bar
from .._validation import as_rng, choice, flag, integer
from ..errors import InputError
from ..measurement import is_plain
from ..model import Model
from ..priors import CountPrior, ScenePrior, UniformCount
from .decide import finish, next_escalation
from .engine import (
    KWork,
    information_criterion,
    laplace_work,
    mixture_work,
    nested_work,
    noise_work,
    quadrature_work,
    ridge_work,
)
from .fits import fit_all
from .mixture import MAX_SOURCES
from .nested_error import scaled_maxcall
from .options import SelectOptions
from .quadrature import qualifies
from .result import SelectionResult
from .scene_priors import prior_factory

__all__ = ["select_k", "METHODS", "K_MAX_LIMIT", "RIDGE_GAIN"]

METHODS = ("auto", "laplace", "nested", "bic", "aic")
#: Hard upper limit of k_max (the evidence of more sources is beyond any sampler budget).
K_MAX_LIMIT = 8
#: Only without the importance-sampling evidence (``importance_draws=0``, or K above
#: :data:`~olsbayes.select.mixture.MAX_SOURCES`): gain of log L over every smaller K
#: (nats) from which a K with a singular Fisher matrix gets the rough prior-ridge
#: Laplace value instead of none (p = 0): far beyond the noise-only gains of an extra
#: source (95 % < 3, largest of 300 draws ~6.5).
RIDGE_GAIN = 10.0


def _sigma_known(prior: ScenePrior) -> None:
    if prior.noise is not None:
        raise InputError("select_k needs sigma known: give ScenePrior(noise=None)")


def _count_prior(k_prior: object, k_max: int) -> np.ndarray:
    prior = UniformCount(k_max) if k_prior is None else k_prior
    if not isinstance(prior, CountPrior):
        raise InputError(f"k_prior must be a CountPrior (UniformCount, PoissonCount); "
                         f"got {type(k_prior).__name__}")
    return np.asarray(prior.log_prob(np.arange(k_max + 1)), float)


def _check(model: object, data: object, k_max: object, method: object, options: object
           ) -> tuple[np.ndarray, int, SelectOptions]:
    """The readings (N,), k_max and the options record, each checked."""
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes Model; got {type(model).__name__}")
    data = model.check_data(data)
    if data.ndim != 1:
        raise InputError(f"data must be one snapshot of shape ({model.n_sensors},); "
                         f"got shape {data.shape}")
    k_max, options = _check_settings(model, k_max, method, options)
    n_live = options.nested.n_live
    p_max = k_max * (model.n_loc + 1)
    if method in ("auto", "nested") and k_max and n_live is not None and n_live <= p_max:
        raise InputError(f"n_live must exceed the {p_max} parameters of k_max = {k_max} "
                         f"sources (method {method!r} may sample them); got {n_live}")
    _check_memory(model, k_max, method, options)
    return data, k_max, options


def _check_memory(model: Model, k_max: int, method: str, options: SelectOptions) -> None:
    """Refuse samplers whose arrays exceed the memory budget, before the first fit.

    Importance sampling evaluates up to twice its draws at once, each a response of
    K sources on N readings; a nested run keeps its live points and at most one
    saved point per likelihood call (``maxcall``).
    """
    n, p_max = model.n_sensors, k_max * (model.n_loc + 1)
    draws = options.laplace.importance_draws
    if method in ("auto", "laplace") and draws and k_max:
        check_memory(f"importance_draws={draws} x {n} readings x K <= {min(k_max, 5)}",
                     8.0 * 2 * draws * n * (min(k_max, 5) + 2))
    if method in ("auto", "nested") and k_max:
        nested = options.nested
        live = nested.n_live if nested.n_live is not None else max(100, 25 * p_max)
        cap = nested.maxcall or scaled_maxcall(p_max, max(live, p_max + 1), n_sensors=n,
                                               n_runs=nested.n_runs)
        check_memory(f"n_live={live}, maxcall={cap} x {p_max} parameters x "
                     f"n_runs={nested.n_runs}",
                     8.0 * nested.n_runs * (live * (n + p_max) * 4 + cap * (p_max + 4)))


def select_k(
    model: Model,
    data: np.ndarray,
    k_max: int = 4,
    *,
    priors: object = None,
    k_prior: object = None,
    i_max: float | None = None,
    method: str = "auto",
    options: SelectOptions | None = None,
    rng: np.random.Generator | int | None = None,
    progress: bool = True,
    frames: bool = False,
) -> SelectionResult:
    """Evidence for K = 0..k_max sources and the posterior over K.

    Every argument is checked before the first ML fit.

    Parameters
    ----------
    model : Model
        Forward model.  With Gaussian noise of known sd and no nuisance terms the
        pipeline below; any other noise model or nuisance terms (their extras
        integrated under their priors) go through :mod:`olsbayes.select.general`.
    data : ndarray, shape (N,), or (F, N) with ``frames``
        One snapshot of the N sub-sensor readings (or F frames of one scene).
    k_max : int
        Largest number of sources considered, 0 <= k_max <= min(8, (N-1)//(d+1)).
    priors : None, mapping {K: ScenePrior} or callable K -> ScenePrior
        Scene priors per K; default :func:`olsbayes.priors.default_priors` with
        ``i_max`` (uniform directions, intensities Uniform(0, i_max)).  The
        evidence, and so the Occam penalty of each extra source (about
        log(i_max / sd_I) + log(2 pi / (sqrt(2 pi) sd_theta)) nats), depends on them.
    k_prior : CountPrior, optional
        Prior on K; default uniform on 0..k_max.
    i_max : float, optional
        Upper end of the default intensity prior; default derived from the
        data (:func:`olsbayes.priors.data_intensity_bound`).  Not with ``priors``.
    method : {"auto", "laplace", "nested", "bic", "aic"}
        Evidence estimator: Laplace everywhere (importance sampling where it is
        not to be trusted); nested sampling (dynesty) for every K >= 1, also
        where the quadrature would apply; Laplace then, for the K in doubt, the
        quadrature (K <= 2 ring sources with uniform directions and
        Uniform(lo, hi) intensities; ``DecisionOptions(quadrature=False)`` turns
        it off) or nested sampling (``auto``); or the pseudo-evidences -BIC/2,
        -AIC/2 (Akaike/Schwarz weights).
    options : SelectOptions, optional
        Laplace trust thresholds and importance sampling, nested-sampling
        settings, the escalation and decision rule, the ML fits; default
        ``SelectOptions()``.
    rng : Generator or seed, optional
        All randomness (ML restarts, importance and nested sampling); streams
        spawned per K.
    progress : bool
        A status line on stderr while the call lasts (after a few seconds): the K
        being worked on and how (importance sampling, nested sampling, with the
        nested run's own status line).
    frames : bool
        ``data`` holds F frames of one static scene.

    Returns
    -------
    SelectionResult
    """
    if frames is not False or (isinstance(model, Model) and not is_plain(model)):
        return _general(model, data, k_max, priors, k_prior, i_max, method, options, rng,
                        frames)
    t0 = time.perf_counter()
    data, k_max, options = _check(model, data, k_max, method, options)
    flag("progress", progress)
    prior_of = prior_factory(model, data, priors, i_max, check=_sigma_known)
    scene_priors = {k: prior_of(k) for k in range(1, k_max + 1)}
    log_pk = _count_prior(k_prior, k_max)
    streams = [s.spawn(3) for s in as_rng(rng).spawn(k_max + 1)]  # fit, nested, importance

    with progress_bar(enabled=bool(progress), desc="select_k", unit=" K",
                      total=k_max) as bar:
        bar.set_postfix_str(f"ML fits of K = 1..{k_max}", refresh=False)
        t_fit = time.perf_counter()
        fitted = fit_all(model, data, k_max, method=options.ml_method,
                         options=options.ml_options, rngs=[s[0] for s in streams])
        t_fit = (time.perf_counter() - t_fit) / max(k_max, 1)
        works: list[KWork] = [noise_work(model, data)]
        for k in range(1, k_max + 1):
            works.append(_evidence(model, data, k, fitted, scene_priors[k], works, method,
                                   options, streams[k], t_fit, bar))
            bar.update(1)
        escalated: dict[int, str] = {}
        if method == "auto":
            escalated = _escalate(model, data, works, log_pk, scene_priors, options, streams,
                                  bar)
    return finish(works, log_pk, method, escalated, options.decision,
                  time.perf_counter() - t0)


def _check_settings(model: Model, k_max: object, method: object, options: object
                    ) -> tuple[int, SelectOptions]:
    """K_max within what the readings can hold, the method's name, the options record."""
    high = min(K_MAX_LIMIT, (model.n_sensors - 1) // (model.n_loc + 1))
    k_max = integer("k_max", k_max, low=0, high=high)
    choice("method", method, METHODS)
    if options is None:
        options = SelectOptions()
    elif not isinstance(options, SelectOptions):
        raise InputError(f"options must be an olsbayes.select.SelectOptions or None; "
                         f"got {type(options).__name__}")
    return k_max, options


def _general(model: Model, data: object, k_max: object, priors: object, k_prior: object,
             i_max: object, method: object, options: object, rng: object, frames: object
             ) -> SelectionResult:
    """select_k for other noise models, nuisance terms or frames (arguments checked first)."""
    from .general import select_general

    k_max, options = _check_settings(model, k_max, method, options)
    return select_general(model, data, k_max, priors=priors,
                          log_pk=_count_prior(k_prior, k_max), i_max=i_max, method=method,
                          options=options, rng=rng, frames=frames)


def _evidence(model: Model, data: np.ndarray, k: int, fitted: dict, prior: ScenePrior,
              works: list[KWork], method: str, options: SelectOptions,
              streams: list[np.random.Generator], t_fit: float, bar) -> KWork:
    """The evidence of K sources by ``method`` (before any escalation of ``auto``).

    ``bar``: the status line, told which K is worked on and how.
    """
    if method in ("bic", "aic"):
        return information_criterion(model, k, fitted[k], method, t_fit)
    lap = options.laplace
    w = laplace_work(model, k, fitted[k], prior, lap.thresholds, t_fit)
    if (method != "nested" and lap.importance_draws and k <= MAX_SOURCES
            and (w.reasons or not np.isfinite(w.value))):
        lower = [fitted[j][1] for j in (k - 1, k - 2, k - 3) if j >= 1]
        bar.set_postfix_str(f"K = {k}: importance sampling")
        w = mixture_work(model, data, w, prior, lower, lap.importance_draws, rng=streams[2])
    gain = w.log_likelihood - max(v.log_likelihood for v in works)
    if not np.isfinite(w.value) and gain >= RIDGE_GAIN:
        # the data need more than K-1 sources but K is not identifiable
        w = ridge_work(model, w, prior)
    if method == "nested":
        bar.set_postfix_str(f"K = {k}: nested sampling")
        w = nested_work(model, data, w, prior, options.nested, rng=streams[1],
                        progress=not bar.disable)
    return w


def _escalate(model: Model, data: np.ndarray, works: list[KWork], log_pk: np.ndarray,
              scene_priors: dict[int, ScenePrior], options: SelectOptions,
              streams: list[list[np.random.Generator]], bar) -> dict[int, str]:
    """``auto``: recompute the K in doubt, most probable first.

    By quadrature where it is exact and within its budget
    (``options.decision.quadrature``, :mod:`olsbayes.select.quadrature`), else by
    nested sampling.  ``works`` is updated in place; returns {K: why} of the K
    sent.  ``bar``: the status line.
    """
    escalated: dict[int, str] = {}
    while len(escalated) < options.decision.max_escalations:
        nxt = next_escalation(works, log_pk, options.decision, set(escalated))
        if nxt is None:
            break
        k, why = nxt
        escalated[k] = why
        bar.total += 1
        work: KWork | str | None = None
        if options.decision.quadrature and qualifies(model, scene_priors[k]):
            bar.set_postfix_str(f"K = {k}: quadrature (the evidence is in doubt)")
            work = quadrature_work(model, data, works, k, scene_priors[k], rng=streams[k][2])
            if isinstance(work, str):  # over budget, or its error too large
                escalated[k] = f"{why} (quadrature not used: {work})"
                work = None
        if work is None:
            bar.set_postfix_str(f"K = {k}: nested sampling (the evidence is in doubt)")
            work = nested_work(model, data, works[k], scene_priors[k], options.nested,
                               rng=streams[k][1], progress=not bar.disable)
        works[k] = work
        bar.update(1)
    return escalated
