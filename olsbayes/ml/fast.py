"""The fast, polynomial-time ML estimator: grid search + joint LM refinement.

Pipeline for a batch of T data vectors (all stages vectorised over trials):

1. :func:`~olsbayes.ml.search.grid_search` -- candidate atom sets on a grid of
   unit-intensity atoms: matching pursuit + alternating projection, runner-up
   positions of each source (:func:`default_runners_up`; not at K = 4,
   :data:`TUPLES_ONLY`), and for K >= 2 the
   best K-tuple of each of ``n_coarse`` differently placed coarse subsets
   (exhaustive, :mod:`~olsbayes.ml.tuples`; 3 subsets, 24 from K = 4 on:
   :func:`default_coarse`); for K = 3 also each subset's best tuple of a
   second, distinct mode (:data:`DISTINCT_SOURCES`).  Cost O(T M N K^2) per
   sweep plus O(T C(M_c, K) K) with C(M_c, K) capped.
2. :func:`~olsbayes.ml.batch.refine_batch` -- one joint bounded
   Levenberg–Marquardt run over all candidates of all trials at once (analytic
   Jacobian); the best likelihood per trial wins.  Steps are cut at the first
   sub-sensor horizon they cross (``kinks=True``): a minimum with a source on
   a kink is then reached in ~10 evaluations instead of ~100 zig-zag ones
   (Fig. 3 at sigma = 0.1: 424 -> 121 evaluations per fit, same optima).
3. Deterministic perturbed restarts around that optimum: every source location
   shifted by fixed sign patterns of ``restart_scale`` grid steps, all refined
   in one more batched LM run.  They reach the neighbouring basins of the
   shallow false minima that the kink of the clipped cosine creates (a
   sub-sensor ~90 deg from a source).  For K <= 2 only fits that ended on a
   kink are restarted; for K >= 3 all (restarting only those would leave 0.1 %
   and 0.5 % of K = 3 fits short at sigma = 0.03 and 0.1, by < 0.2 in log L).
4. Kink hops (planar arrays of angles, kinked law, K >= 2): each source is
   moved just past the nearest angle, either way, at which a sub-sensor crosses
   its 90 deg horizon, and all 2K hops are refined in one batched LM run.  The
   likelihood is smooth only between such crossings, so with several sources
   it has shallow local minima in neighbouring cells ~1 CRLB std apart, which
   the fixed-size restarts step over (measured on a 30-ring at sigma = 0.01:
   10 % of fits of a K = 4 scene and 0.5 % of fits of random K = 2 scenes ended
   in one; none after one round of hops).
5. Fits that end with a source on a kink are polished with that source's
   location held fixed (LM's one-sided Jacobian stalls there otherwise).
6. K = 2, 3 on a ring with the clipped cosine: fits with close or lopsided
   sources are refitted by exact enumeration (:mod:`~olsbayes.ml.pairs`).

In stages 2-4 a run that comes within ``DEDUPE_TOL`` (max norm) of an optimum
already found for its trial (the stage's base fit, or an earlier start's
converged run) stops there: the starts of a trial mostly share one optimum
(K = 3: 10 candidates, 1.03 distinct optima per trial).  Measured on 3000 fits
of each benchmark setting: no log-likelihood changed by more than 1e-12;
evaluations per fit K = 3 197 -> 128, Fig. 3 98 -> 63.  With the clipped cosine
on a ring a run also stops as soon as it enters the linear cell of such an
optimum (:data:`olsbayes.ml._kernel.CELL_STOP`): chi^2 is convex in the phasors
there, so the run would end at that optimum (36,000 random K = 2..4 fits: 2
differ, by < 1 in log L; 35-45 % fewer evaluations, 7-21 % less time).

Being deterministic, a batch fit equals a loop of single fits.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..circular import wrap_angle
from ..model import Model
from .batch import LMOutcome, refine_batch
from .grid import atoms, grid_step
from .pairs import exact_applies, exact_pairs
from .search import grid_search
from .tuples import TUPLE_BUDGET

__all__ = ["fit_fast", "restart_patterns", "hop_starts", "default_coarse"]

#: Kink hops apply from this many sources on (K = 1 has the kink-triggered restarts).
HOP_MIN_SOURCES = 2

#: LM runs of the starts cut steps at sub-sensor horizons (refine_batch ``kinks``).
KINK_CUTS = True

#: A run of a trial's starts stops within this distance (max norm, rad and
#: intensity units) of an optimum that an earlier run of the trial converged to
#: (refine_batch ``dedupe_tol``; 0 turns it off).
DEDUPE_TOL = 1e-4

#: Numbers of sources for which each coarse subset also gives the best tuple of a second,
#: distinct mode (:func:`~olsbayes.ml.tuples.tuple_search`): near-equilateral K = 3
#: scenes have a rotated alias that the best coarse tuple of each of the 3 subsets often
#: picks (see :func:`default_coarse`).  K = 2 gains nothing; K >= 4 has 24 subsets.
DISTINCT_SOURCES = (3,)

#: Tuple budget per coarse subset where the second modes are searched too (the default
#: 5,000 elsewhere): 27 instead of 32 coarse atoms on a 30-ring; 16 instead of 17 of
#: 22,000 fits of random K = 3 scenes (sigma 1e-4..0.1) short of the exact optimum,
#: for 14 % less time.
DISTINCT_BUDGET = 3_000

#: Coarse tuple-search subsets by default: K <= 3, K >= 4 (see :func:`default_coarse`).
COARSE_SETS = (3, 24)

#: Numbers of sources for which the search's candidates are the coarse subsets' best
#: tuples only, without pursuit + alternation and its runners-up (grid_search
#: ``pursuit``), unless there is no coarse plan (K >= 5 is unmeasured: it keeps them).
#: At K = 4 on a 30-ring those 9 of 30 LM starts and the pursuit cost 22-27 % of a
#: batched fit; without them, fits short of the exact optimum (fit_exact), of 4,000
#: each (200 random scenes x 20 draws): neighbours >= 30 deg, sigma = 0.01: 3 -> 8
#: (by > 1 in log L: 1 -> 3); sigma = 1e-3: 0 -> 0; neighbours >= 5 deg, sigma =
#: 0.01: 10 -> 12; sigma = 1e-3: 14 -> 16.
TUPLES_ONLY = (4,)


def default_coarse(k: int) -> int:
    """Default number of coarse subsets of the K-tuple search for K sources.

    Three suffice up to K = 3 (random well-separated scenes on a 30-ring at
    sigma = 0.01: 1 fit in 12,000 short of the optimum an LM run started at the
    truth reaches, by 7e-6).  From K = 4 on the coarse subsets hold only ~20 atoms
    (the tuple budget), the likelihood has many shallow cells, and near-ambiguous
    configurations far apart in angle compete: with 3 subsets 6-7 % of such fits
    stopped short of the truth's basin (by up to ~60 in log-likelihood; 20
    multistart starts: 3.5 %).  24 differently placed subsets cut that to 0.08-0.10 %
    (two independent sets of 40 x 300 and 80 x 200 scenes) for 2.4x the time; their
    tuples alone, without the pursuit (:data:`TUPLES_ONLY`), to 0.20 % (200 x 20).
    """
    return COARSE_SETS[0] if k <= 3 else COARSE_SETS[1]


def default_runners_up(model: Model, k: int) -> int:
    """Runner-up positions per source added as search candidates (``grid_search`` n_alt).

    2, except where :mod:`~olsbayes.ml.pairs` refits close or lopsided fits exactly
    and the coarse subsets' second modes are searched (K = 3 on a ring with the
    clipped cosine): there dropping them left 16 instead of 14 of 22,000 fits of
    random K = 3 scenes on a 30-ring (sigma 1e-4..0.1) short of the optimum of
    :func:`~olsbayes.ml.exact.fit_exact` (1 instead of 2 by more than 1 in log L),
    for 25 % less time.
    """
    return 0 if k in DISTINCT_SOURCES and exact_applies(model, k) else 2


def restart_patterns(k: int, d: int, n: int) -> np.ndarray:
    """``n`` deterministic sign patterns for the restarts, shape (n, K, d).

    The first four are all +1, all -1, alternating +-, alternating -+ (over the
    flattened K*d location coordinates); further ones cycle through a fixed
    Hadamard-like sequence.
    """
    m = k * d
    j = np.arange(m)
    base = [np.ones(m), -np.ones(m), (-1.0) ** j, -((-1.0) ** j)]
    extra = 0
    while len(base) < n:
        extra += 1
        base.append(np.where(((j + 1) >> (extra - 1)) & 1, 1.0, -1.0) * (-1.0) ** extra)
    return np.array(base[:n]).reshape(n, k, d)


def _take(out: LMOutcome, rows: np.ndarray) -> LMOutcome:
    return LMOutcome(out.x[rows], out.chi2[rows], out.converged[rows],
                     out.n_evaluations[rows], out.stalled[rows])


def _kinked(model: Model, x: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """:func:`~olsbayes.bounds.kink_sources` of fits x (T, P), compiled: bool (T, K)."""
    from . import _fit_kernel  # numba is imported on first use

    if not model.sensitivity.kink:
        return np.zeros((x.shape[0], x.shape[1] // (model.n_loc + 1)), bool)
    return _fit_kernel.on_kink(model, x, atol)


def _on_kink(model: Model, x: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """Trials (T,) with a source within ~atol rad of a sub-sensor's 90 deg horizon."""
    return np.any(_kinked(model, x, atol), axis=-1)


def _kink_polish(model: Model, data: np.ndarray, out: LMOutcome, max_iter: int) -> LMOutcome:
    """Re-optimise the other parameters of fits with a source pinned on a kink.

    At a kink the one-sided Jacobian misleads LM, which then stops with the
    remaining parameters not quite optimal; holding the kinked source's
    location fixed makes the rest a smooth problem.
    """
    if not model.sensitivity.kink:
        return out
    kinked = _kinked(model, out.x, atol=1e-6)  # (T, K)
    rows = np.flatnonzero(kinked.any(axis=1))
    if rows.size == 0:
        return out
    d1 = model.n_loc + 1
    frozen = np.repeat(kinked[rows], d1, axis=1)
    frozen[:, d1 - 1 :: d1] = False  # intensities stay free
    new = refine_batch(model, data[rows], out.x[rows], max_iter=max_iter, frozen=frozen)
    x, chi2, nev = out.x.copy(), out.chi2.copy(), out.n_evaluations.copy()
    nev[rows] += new.n_evaluations
    better = new.chi2 < chi2[rows]
    x[rows[better]], chi2[rows[better]] = new.x[better], new.chi2[better]
    return LMOutcome(x, chi2, out.converged, nev, out.stalled)


def _restart(
    model: Model, data: np.ndarray, out: LMOutcome, delta: np.ndarray, patterns: np.ndarray,
    max_iter: int,
) -> LMOutcome:
    """Perturbed restarts around the refined optimum (all patterns in one LM run).

    Every trial for K >= 3; for K <= 2 only trials that ended on a kink.
    """
    k, d = patterns.shape[1:]
    rows = np.arange(out.x.shape[0])
    if k <= 2:
        rows = np.flatnonzero(out.stalled | _on_kink(model, out.x))
    if rows.size == 0:
        return out
    base = out.x[rows].reshape(rows.size, 1, k, d + 1)
    starts = np.repeat(base, patterns.shape[0], axis=1)
    starts[..., :d] += patterns * delta
    return _merge(out, rows, _refine_starts(model, data[rows], starts, max_iter,
                                            _known(_take(out, rows))))


def _known(out: LMOutcome) -> np.ndarray:
    """Fits that converged without stalling (else NaN rows): known optima, (T, P)."""
    return np.where((out.converged & ~out.stalled)[:, None], out.x, np.nan)


def _merge(out: LMOutcome, rows: np.ndarray, new: LMOutcome) -> LMOutcome:
    """Replace the fits ``rows`` of ``out`` by ``new`` where it is strictly better."""
    x, chi2 = out.x.copy(), out.chi2.copy()
    conv, nev, stalled = out.converged.copy(), out.n_evaluations.copy(), out.stalled.copy()
    nev[rows] += new.n_evaluations
    better = new.chi2 < chi2[rows] * (1 - 1e-12)
    sel = rows[better]
    x[sel], chi2[sel], conv[sel] = new.x[better], new.chi2[better], new.converged[better]
    stalled[sel] = new.stalled[better]
    return LMOutcome(x, chi2, conv, nev, stalled)


def hop_starts(model: Model, x: np.ndarray) -> np.ndarray:
    """Kink hops of fits x (T, P) of a planar (angle) model: starts (T, 2K, P).

    Start 2j (2j + 1) moves source j's angle up (down) just past the nearest
    angle at which some sub-sensor sits on the source's 90 deg horizon, i.e. into
    the neighbouring cell where the likelihood is a different smooth function.
    """
    k = x.shape[1] // 2
    nrm = model.array.normals
    phi = np.arctan2(nrm[:, 1], nrm[:, 0])
    crossings = np.concatenate([phi + np.pi / 2, phi - np.pi / 2])  # (2N,)
    diff = wrap_angle(crossings - x[:, 0::2, None])  # (T, K, 2N)
    up = np.where(diff > 1e-9, diff, np.inf).min(axis=-1)  # (T, K)
    down = np.where(diff < -1e-9, diff, -np.inf).max(axis=-1)
    eps = 0.05 * np.pi / model.n_sensors  # 5 % of the mean gap between crossings
    starts = np.repeat(x[:, None, :], 2 * k, axis=1)
    j = np.arange(k)
    starts[:, 2 * j, 2 * j] += up + eps
    starts[:, 2 * j + 1, 2 * j] += down - eps
    return starts


def _kink_hops(model: Model, data: np.ndarray, out: LMOutcome, max_iter: int) -> LMOutcome:
    """One round of kink hops for every fit (angle models, kinked law, K >= 2)."""
    k = out.x.shape[1] // (model.n_loc + 1)
    if model.kind != "angle" or not model.sensitivity.kink or k < HOP_MIN_SOURCES:
        return out
    from . import _fit_kernel  # numba is imported on first use

    t = out.x.shape[0]
    starts = _fit_kernel.hop_starts(model, out.x).reshape(t, 2 * k, k, 2)  # == hop_starts
    return _merge(out, np.arange(t), _refine_starts(model, data, starts, max_iter,
                                                    _known(out)))


def fit_fast(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    grid: np.ndarray,
    *,
    n_restarts: int = 4,
    restart_scale: float = 3.0,
    n_coarse: int | None = None,
    max_iter: int = 300,
) -> LMOutcome:
    """Fast ML fits of a batch ``data`` (T, N); returns the raw (T, P) outcome.

    ``n_coarse`` None: :func:`default_coarse` of K.
    """
    k, d = n_sources, model.n_loc
    n_coarse = default_coarse(k) if n_coarse is None else n_coarse
    g = atoms(model, grid)
    distinct = k in DISTINCT_SOURCES
    idx, inten, _ = grid_search(g, data, k, n_coarse=n_coarse, distinct=distinct,
                                n_alt=default_runners_up(model, k),
                                budget=DISTINCT_BUDGET if distinct else TUPLE_BUDGET,
                                pursuit=k not in TUPLES_ONLY)
    starts = np.concatenate([grid[idx], inten[..., None]], axis=-1)  # (T, C, K, d+1)
    out = _refine_starts(model, data, starts, max_iter, keep=True)
    found = out.alternatives  # the search candidates' optima (olsbayes.ml.rivals)
    if n_restarts:
        delta = restart_scale * grid_step(model, grid)
        out = _restart(model, data, out, delta, restart_patterns(k, d, n_restarts), max_iter)
    out = _kink_hops(model, data, out, max_iter)
    out = dataclasses.replace(_kink_polish(model, data, out, max_iter), alternatives=found)
    return exact_pairs(model, data, out)


def _refine_starts(
    model: Model, data: np.ndarray, starts: np.ndarray, max_iter: int,
    known: np.ndarray | None = None, keep: bool = False,
) -> LMOutcome:
    """One batched LM run over starts (T, C, K, d+1); the best chi^2 per trial wins.

    Runs reaching an optimum already found for their trial (``known`` (T, P),
    NaN rows: none, or an earlier start's) stop there (``DEDUPE_TOL``).
    ``keep``: every converged run's optimum goes to ``alternatives``.
    """
    t, c = starts.shape[:2]
    if known is None:
        known = np.full((t, starts.shape[2] * starts.shape[3]), np.nan)
    cand = refine_batch(model, np.repeat(data, c, axis=0), starts.reshape(t * c, -1),
                        max_iter=max_iter, kinks=KINK_CUTS, group=c, known=known,
                        dedupe_tol=DEDUPE_TOL)
    pick = np.arange(t) * c + np.argmin(cand.chi2.reshape(t, c), axis=1)
    out = _take(cand, pick)
    alt = None
    if keep:
        alt = (cand.x.reshape(t, c, -1),
               np.where(cand.converged, cand.chi2, np.inf).reshape(t, c))
    return LMOutcome(out.x, out.chi2, out.converged,
                     cand.n_evaluations.reshape(t, c).sum(axis=1), out.stalled, alt)
