"""select_k: the posterior over the number of sources K = 0..K_max.

Pipeline.  K = 0 (noise only) has a closed-form evidence.  Every K >= 1 gets an
ML fit (non-negative intensities: unconstrained fits let BIC/AIC pick a spurious
extra source on 5-8 % of three-source scenes) and its Laplace evidence with
trust diagnostics.  Where Laplace is not to be trusted or undefined (an extra
source at intensity 0 with a free location, a singular Fisher matrix, a weak or
close source) the evidence is computed instead by importance sampling over the
source locations with the intensities integrated analytically
(:mod:`olsbayes.select.mixture`, a few ms); Laplace is kept where it is trusted
(within 0.3 nats of nested sampling there).  ``method="auto"`` then recomputes by
nested sampling only the competing K whose Laplace value is not to be trusted
(whatever replaced it), or whose comparison
with the best K is not decisive (at most ``max_escalations`` K, most probable
first).  Finally p(K | data) is proportional to Z_K p(K), and the chosen K is the
*smallest* K within ``tie`` nats of the most probable one: when the data barely
prefer more sources, the simpler scene is reported (and a note says so).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping

import numpy as np

from .._validation import as_rng, integer, nonnegative_float, positive_float
from ..errors import EvidenceWarning, InputError
from ..model import Model
from .engine import (
    KWork,
    information_criterion,
    laplace_work,
    mixture_doubt,
    mixture_work,
    nested_work,
    noise_work,
    ridge_work,
)
from .fits import fit_all
from .mixture import MAX_SOURCES
from .result import KEvidence, SelectionResult

__all__ = ["select_k", "METHODS", "K_MAX_LIMIT"]

METHODS = ("auto", "laplace", "nested", "bic", "aic")
#: Hard upper limit of k_max (the evidence of more sources is beyond any sampler budget).
K_MAX_LIMIT = 8
#: Only without the importance-sampling evidence (``importance_draws=0``, or K above
#: :data:`~olsbayes.select.mixture.MAX_SOURCES`): gain of log L over every smaller K
#: (nats) from which a K with a singular Fisher matrix gets the rough prior-ridge
#: Laplace value instead of none (p = 0): far beyond the noise-only gains of an extra
#: source (95 % < 3, largest of 300 draws ~6.5).
RIDGE_GAIN = 10.0
#: Nats within which a trusted Laplace comparison counts as at the decision boundary.
TRUSTED_MARGIN = 1.0


def _prior_factory(model: Model, data: np.ndarray, priors: object, i_max: float | None
                   ) -> Callable[[int], object]:
    from ..priors import ScenePrior, default_priors

    if priors is None:
        # one data-derived bound shared by every K (plates: over the default box)
        bound = default_priors(model, 1, data=data).intensity.upper if i_max is None else (
            positive_float("i_max", i_max))
        return lambda k: default_priors(model, k, i_max=bound)
    if i_max is not None:
        raise InputError("give either priors= or i_max=, not both")
    if isinstance(priors, Mapping):
        get = priors.__getitem__
    elif callable(priors):
        get = priors
    else:
        raise InputError(
            "priors must be None, a mapping {K: ScenePrior} or a callable K -> ScenePrior; "
            f"got {type(priors).__name__}"
        )

    def factory(k: int):
        try:
            p = get(k)
        except KeyError:
            raise InputError(f"priors has no entry for K = {k}") from None
        if not isinstance(p, ScenePrior) or p.n_sources != k or p.kind != model.kind:
            raise InputError(f"priors for K = {k} must be a ScenePrior of {k} {model.kind!r} "
                             f"sources; got {p!r}")
        if p.noise is not None:
            raise InputError("select_k needs sigma known: give ScenePrior(noise=None)")
        return p

    return factory


def _count_prior(k_prior: object, k_max: int) -> np.ndarray:
    from ..priors import CountPrior, UniformCount

    prior = UniformCount(k_max) if k_prior is None else k_prior
    if not isinstance(prior, CountPrior):
        raise InputError(f"k_prior must be a CountPrior (UniformCount, PoissonCount); "
                         f"got {type(k_prior).__name__}")
    return np.asarray(prior.log_prob(np.arange(k_max + 1)), float)


def _next_escalation(works: list[KWork], log_pk: np.ndarray, decisive: float, tie: float,
                     min_gain: float, done: set[int]) -> tuple[int, str] | None:
    """The most probable K still needing nested sampling, and why (None: none).

    Candidates: the K within ``decisive`` nats of the most probable one whose
    Laplace value is untrusted, or trusted but within ``TRUSTED_MARGIN`` of the
    decision boundary (log odds = +-tie) of a non-decisive comparison, then a
    neighbour of the most probable K whose Laplace value does not exist, unless
    its likelihood maximum (an upper bound on Z_K) already loses decisively.  A K
    above the most probable one whose ML fit gains less than ``min_gain`` nats of
    log-likelihood over it is not sent: its extra source only fits noise; nor is
    the comparison with such a K a reason to send the most probable one (nested
    sampling of the latter would not sharpen the former, whose value comes from
    Laplace or from importance sampling over its free locations).
    """
    score = np.array([w.value for w in works]) + log_pk
    finite = np.isfinite(score)
    top = int(np.nanargmax(np.where(finite, score, -np.inf)))
    order = np.argsort(-np.where(finite, score, -np.inf), kind="stable")
    competing = [int(k) for k in order if finite[k] and score[k] >= score[top] - decisive]
    rivals = [k for k in competing if not _noise_only(works, k, top, min_gain)]
    candidates: list[tuple[int, str]] = []
    for k in rivals:
        w = works[k]
        if k == 0 or w.method == "nested":
            continue
        why = list(w.reasons)
        if len(rivals) > 1:
            other = rivals[1] if k == top else top
            gap = score[k] - score[other]
            # a trusted Laplace value (error ~0.3 nats) matters only near the decision
            if why or abs(abs(gap) - tie) < TRUSTED_MARGIN:
                how = "importance sampling" if "importance" in (
                    w.method, works[other].method) else "Laplace"
                why.insert(0, f"not decisive against K={other} ({gap:+.2f} nats by {how})")
        if why:
            candidates.append((k, "; ".join(why)))
    for k in (top - 1, top + 1):  # a neighbour whose Laplace value does not exist
        if (0 < k < len(works) and not finite[k] and works[k].method != "nested"
                and not _noise_only(works, k, top, min_gain)
                and _could_compete(works[k], log_pk[k], score[top] - decisive)):
            candidates.append((k, "Laplace undefined: " + "; ".join(works[k].reasons)))
    for k, why in candidates:
        if k not in done:
            return k, why
    return None


def _could_compete(work: KWork, log_pk: float, floor: float) -> bool:
    """Whether K's evidence can reach ``floor``: log Z_K <= max log L_K (the prior
    integrates to 1), so a K whose likelihood maximum plus log p(K) lies below the
    decisive floor of the most probable K loses whatever its evidence is."""
    return bool(work.log_likelihood + log_pk >= floor)


def _noise_only(works: list[KWork], k: int, top: int, min_gain: float) -> bool:
    """K > top and its ML fit gains < min_gain nats of log L over K = top."""
    return k > top and works[k].log_likelihood - works[top].log_likelihood < min_gain


def _choose(score: np.ndarray, tie: float) -> tuple[int, list[str]]:
    top = int(np.argmax(score))
    near = np.flatnonzero(score >= score[top] - tie)
    best = int(near.min())
    notes = []
    if best != top:
        notes.append(
            f"K={best} chosen over the most probable K={top}: posterior log odds "
            f"{score[top] - score[best]:.2f} < tie={tie:.2f} nats, so the data do not "
            "support the extra source(s); the smaller scene is preferred"
        )
    return best, notes


def select_k(
    model: Model,
    data: np.ndarray,
    k_max: int = 4,
    priors: object = None,
    method: str = "auto",
    rng: np.random.Generator | int | None = None,
    *,
    k_prior: object = None,
    i_max: float | None = None,
    maxcall: int = 300_000,
    nlive: int | None = None,
    decisive: float = math.log(100.0),
    tie: float = math.log(3.0),
    max_escalations: int = 2,
    min_gain: float = 3.0,
    dlogz: float = 0.5,
    thresholds: Mapping[str, float] | None = None,
    fit_kwargs: Mapping[str, object] | None = None,
    importance_draws: int = 500,
) -> SelectionResult:
    """Evidence for K = 0..k_max sources and the posterior over K.

    Parameters
    ----------
    model : Model
        Forward model with known noise sd ``model.sigma``.
    data : ndarray, shape (N,)
        One snapshot of the N sub-sensor readings.
    k_max : int
        Largest number of sources considered, 0 <= k_max <= min(8, (N-1)//(d+1)).
    priors : None, mapping {K: ScenePrior} or callable K -> ScenePrior
        Scene priors per K; default :func:`olsbayes.priors.default_priors` with
        ``i_max`` (uniform directions, intensities Uniform(0, i_max)).  The
        evidence, and so the Occam penalty of each extra source (about
        log(i_max / sd_I) + log(2 pi / (sqrt(2 pi) sd_theta)) nats), depends on them.
    method : {"auto", "laplace", "nested", "bic", "aic"}
        Evidence estimator: Laplace everywhere; nested sampling (dynesty) for
        every K >= 1; Laplace then nested sampling for the K in doubt (``auto``);
        or the pseudo-evidences -BIC/2, -AIC/2 (Akaike/Schwarz weights).
    rng : Generator or seed, optional
        All randomness (ML restarts, nested sampling); streams spawned per K.
    k_prior : CountPrior, optional
        Prior on K; default uniform on 0..k_max.
    i_max : float, optional
        Upper end of the default intensity prior; default derived from the
        data (:func:`olsbayes.priors.data_intensity_bound`).  Not with ``priors``.
    maxcall : int
        Cap on likelihood calls per nested-sampling run.
    nlive : int, optional
        dynesty live points (default max(100, 25 P)).
    decisive : float
        Log odds (nats) beyond which a comparison is decisive; default log 100.
    tie : float
        Candidates within ``tie`` nats of the most probable K count as tied and
        the smallest of them is chosen; default log 3 (Jeffreys' "barely worth
        mentioning").  0 picks the most probable K.
    max_escalations : int
        At most this many K are sent to nested sampling by ``auto``.
    min_gain : float
        ``auto`` does not escalate a K above the most probable one whose ML
        log-likelihood exceeds that K's by less than this (nats): on K = 1 truths
        (ring N = 30) the gain of a second source is below 3 nats in 95 % of
        noise draws.
    dlogz : float
        dynesty's stopping tolerance on the remaining evidence (nats).
    thresholds : mapping, optional
        Overrides of :data:`olsbayes.select.diagnostics.THRESHOLDS`.
    fit_kwargs : mapping, optional
        Extra keyword arguments of :func:`olsbayes.ml.fit_ml`.
    importance_draws : int
        Initial draws of the mixture importance sampler
        (:func:`~olsbayes.select.mixture.mixture_log_evidence`) that replaces every
        untrusted or undefined Laplace value for K <= 5 (methods ``laplace`` and
        ``auto``): intensities at their bound 0, (nearly) free locations, singular
        Fisher matrices.  Doubled once if its error exceeds 0.2 nats.  0
        restores the bare Laplace rule (an undefined Laplace value gets the rough
        prior-ridge fallback if its ML fit gains >= ``RIDGE_GAIN`` = 10 nats over
        every smaller K, else p = 0).

    Returns
    -------
    SelectionResult
    """
    t0 = time.perf_counter()
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes Model; got {type(model).__name__}")
    data = model.check_data(data)
    if data.ndim != 1:
        raise InputError(f"data must be one snapshot of shape ({model.n_sensors},); "
                         f"got shape {data.shape}")
    high = min(K_MAX_LIMIT, (model.n_sensors - 1) // (model.n_loc + 1))
    k_max = integer("k_max", k_max, low=0, high=high)
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}; got {method!r}")
    decisive = positive_float("decisive", decisive)
    tie = nonnegative_float("tie", tie)
    max_escalations = integer("max_escalations", max_escalations, low=0)
    min_gain = nonnegative_float("min_gain", min_gain)
    maxcall = integer("maxcall", maxcall, low=1000)
    importance_draws = integer("importance_draws", importance_draws, low=0)
    if 0 < importance_draws < 100:
        raise InputError(f"importance_draws must be 0 or >= 100; got {importance_draws}")
    streams = as_rng(rng).spawn(k_max + 1)
    prior_of = _prior_factory(model, data, priors, i_max)
    log_pk = _count_prior(k_prior, k_max)
    nested_opts = {"maxcall": maxcall, "nlive": nlive, "dlogz": positive_float("dlogz", dlogz)}

    pairs = [s.spawn(3) for s in streams]  # (fit, nested, importance) streams per K
    t_fit = time.perf_counter()
    fitted = fit_all(model, data, k_max, [p[0] for p in pairs], fit_kwargs)
    t_fit = (time.perf_counter() - t_fit) / max(k_max, 1)
    works: list[KWork] = [noise_work(model, data)]
    for k in range(1, k_max + 1):
        if method in ("bic", "aic"):
            works.append(information_criterion(model, k, fitted[k], method, t_fit))
            continue
        w = laplace_work(model, k, fitted[k], prior_of(k), thresholds, t_fit)
        if (method != "nested" and importance_draws and k <= MAX_SOURCES
                and (w.reasons or not np.isfinite(w.value))):
            lower = [fitted[j][1] for j in (k - 1, k - 2, k - 3) if j >= 1]
            w = mixture_work(model, data, w, prior_of(k), lower, pairs[k][2], importance_draws)
        gain = w.log_likelihood - max(v.log_likelihood for v in works)
        if not np.isfinite(w.value) and gain >= RIDGE_GAIN:
            # the data need more than K-1 sources but K is not identifiable
            w = ridge_work(model, w, prior_of(k))
        if method == "nested":
            w = nested_work(model, data, w, prior_of(k), pairs[k][1], **nested_opts)
        works.append(w)

    escalated: dict[int, str] = {}
    if method == "auto":
        while len(escalated) < max_escalations:
            nxt = _next_escalation(works, log_pk, decisive, tie, min_gain, set(escalated))
            if nxt is None:
                break
            k, why = nxt
            escalated[k] = why
            works[k] = nested_work(model, data, works[k], prior_of(k), pairs[k][1],
                                   **nested_opts)
    return _finish(works, log_pk, method, escalated, tie, decisive, min_gain,
                   time.perf_counter() - t0)


def _finish(works: list[KWork], log_pk: np.ndarray, method: str, escalated: dict[int, str],
            tie: float, decisive: float, min_gain: float, seconds: float) -> SelectionResult:
    value = np.array([w.value for w in works])
    score = np.where(np.isfinite(value), value + log_pk, -np.inf)
    prob = np.exp(score - score.max())
    prob /= prob.sum()
    best, notes = _choose(score, tie)
    for w in works:
        noise_only = method == "auto" and w.method in ("laplace", "importance") and bool(
            w.reasons) and w.k > best and w.log_likelihood - works[best].log_likelihood < min_gain
        if noise_only:
            low = ("; its p(K) rests on the untrusted Laplace value, which can be several "
                   "nats low for an over-complete K (a source split within one sensor spacing "
                   "predicts the same readings)") if np.isfinite(w.value) else ""
            if w.method == "importance" and np.isfinite(w.value):
                low = (f"; its p(K) rests on the importance-sampling evidence (+-{w.error:.2f} "
                       "nats), which integrates the free location of the extra source")
            notes.append(f"K={w.k}: not escalated, its ML fit gains only "
                         f"{w.log_likelihood - works[best].log_likelihood:.2f} nats of log L "
                         f"over K={best} (< min_gain={min_gain:g}): the extra source fits "
                         f"noise{low}")
        if not np.isfinite(w.value):
            notes.append(f"K={w.k}: no evidence estimate ({'; '.join(w.reasons)}); p(K) set to 0")
        elif w.method == "laplace" and w.reasons and score[w.k] >= score.max() - decisive:
            notes.append(f"K={w.k}: Laplace evidence not to be trusted ({'; '.join(w.reasons)})")
        elif w.method == "importance" and not noise_only and (
                score[w.k] >= score.max() - decisive):
            notes.append(f"K={w.k}: Laplace evidence not to be trusted, importance sampling "
                         f"over the locations used instead ({w.value:.2f} +- {w.error:.2f} "
                         "nats)")
    untrusted_best = (works[best].method == "laplace" and works[best].reasons) or (
        mixture_doubt(works[best]))
    if untrusted_best and method == "laplace":
        what = "an importance-sampling" if works[best].method == "importance" else "a Laplace"
        warnings.warn(f"the chosen K={best} rests on {what} evidence that is not to be "
                      f"trusted ({'; '.join(works[best].reasons)}); try method='auto'",
                      EvidenceWarning, stacklevel=3)
    evidences = tuple(
        KEvidence(
            k=w.k, log_evidence=float(w.value), error=float(w.error), method=w.method,
            log_likelihood=float(w.log_likelihood), n_params=int(w.params.size),
            params=w.params, laplace=float(w.laplace), trusted=not w.reasons,
            reasons=tuple(w.reasons), n_calls=int(w.n_calls), seconds=float(w.seconds),
            fit=w.fit, origin=w.origin,
        )
        for w in works
    )
    return SelectionResult(
        ks=np.arange(len(works)), log_evidence=value,
        error=np.array([w.error for w in works]), log_prior_k=log_pk, probabilities=prob,
        best=best, method=method, evidences=evidences, escalated=escalated,
        notes=tuple(notes), seconds=seconds,
    )
