"""The fast, polynomial-time ML estimator: grid search, then joint LM refinement.

Pipeline for a batch of T data vectors (every stage vectorised over them; the
knobs and their per-K defaults are :class:`~olsbayes.ml.fast.options.FastOptions`):

1. :func:`~olsbayes.ml.fast.search.grid_search` -- candidate atom sets on a grid
   of unit-intensity atoms: matching pursuit + alternating projection with the
   runner-up positions of each source, and for K >= 2 the best K-tuple of each of
   ``n_coarse`` differently placed coarse subsets (exhaustive,
   :mod:`~olsbayes.ml.fast.tuples`), with ``distinct_modes`` also each subset's
   best tuple of a second, distinct mode.  Cost: the correlations of every data
   vector with every atom, O(T M N) -- O(T (M + N)) on a ring with the clipped
   cosine, whose atoms each light an arc of the sub-sensors (prefix sums,
   :func:`~olsbayes.ml.fast.search.arc_views`), O(T (M + L)) on a sphere with it,
   whose atoms' correlations follow one from another over a spanning tree (L ~ M N
   delta / pi for grid spacing delta, :func:`~olsbayes.ml.fast.search.tree_views`)
   -- then O(T M K^2) per sweep
   through the atoms' Gram matrix (O(T M N K^2) without it), plus
   O(T C(M_c, K) K) with C(M_c, K) capped by the tuple budget.
2. :func:`~olsbayes.ml.fast.refine.refine_starts` -- one joint bounded
   Levenberg–Marquardt run over all candidates of all data vectors (analytic
   Jacobian); the best likelihood per data vector wins.  Steps are cut at the
   first sub-sensor horizon they cross (``kink_cuts``, rings), so a minimum with a
   source on a kink is reached in a few steps instead of a long zig-zag.
3. :func:`~olsbayes.ml.fast.refine.restart` -- deterministic perturbed restarts
   around that optimum (``n_restarts`` sign patterns of ``restart_scale`` grid
   steps), all refined in one more batched LM run.
   Then (``scatter``, K >= 5) :func:`~olsbayes.ml.fast.scatter.scattered` -- fixed
   configurations spread over the whole source space, refined in one more LM run --
   and (``slide``, K >= 5) :func:`~olsbayes.ml.fast.slide.slide` -- sweeps of
   moves of one or two sources to the atoms best correlated with the residual,
   from the best distinct optima found so far.
4. :func:`~olsbayes.ml.fast.refine.kink_hops` -- each source moved just past its
   nearest sub-sensor horizon, either way, into the neighbouring smooth cell of
   the likelihood (``kink_hops``: planar arrays with a kinked law, K >= 2).
5. :func:`~olsbayes.ml.fast.refine.kink_polish` -- fits with a source on a kink
   re-optimised with that source's location held (LM's one-sided Jacobian stalls
   there otherwise); on a sphere (``kink_cuts``) every fit refined again, by LM
   that cuts its steps at horizons and probes and holds its sources there.
6. :func:`~olsbayes.ml.fast.escalate.escalate` -- fits with close or lopsided
   sources refitted by exact enumeration (``escalate``: rings with the clipped
   cosine, K = 2, 3 by default).

In stages 2-4 a run that comes within ``dedupe_tol`` (max norm) of an optimum
already found for its data vector (the stage's base fit, or an earlier start's
converged run) stops there, since the starts of a fit mostly share one optimum;
with the clipped cosine on a ring a run also stops as soon as it enters the linear
cell of such an optimum (``cell_stop``): chi^2 is convex in the source phasors
there, so the run would end at that optimum.

Being deterministic, a batch fit equals a loop of single fits.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...model import Model
from ..atoms import atoms, grid_step
from ..outcome import FitOutcome
from .escalate import escalate
from .options import FastOptions
from .refine import kink_hops, kink_polish, refine_starts, restart
from .scatter import scattered
from .search import grid_search, model_views
from .slide import slide

__all__ = ["fit_fast"]


def fit_fast(model: Model, data: np.ndarray, n_sources: int, grid: np.ndarray,
             options: FastOptions) -> FitOutcome:
    """Fast ML fits of a batch ``data`` (T, N) of K sources; the raw (T, P) outcome.

    ``grid`` (M, d): candidate locations; ``options``: resolved for K
    (:meth:`FastOptions.resolve`).  ``alternatives`` of the outcome hold the
    optima the search candidates and the scattered starts reached (for
    :mod:`olsbayes.ml.rivals`).
    """
    k = n_sources
    g = atoms(model, grid)
    arcs, tree = model_views(model, g, grid)
    idx, inten, _ = grid_search(g, data, k, options, arcs, tree)
    starts = np.concatenate([grid[idx], inten[..., None]], axis=-1)  # (T, C, K, d+1)
    out = refine_starts(model, data, starts, options, keep=True)
    found = out.alternatives
    if options.n_restarts:
        out = restart(model, data, out, options.restart_scale * grid_step(model, grid), options)
    pool = found
    if options.scatter:
        out = scattered(model, data, out, grid, options)
        pool = tuple(np.concatenate([a, b], axis=1) for a, b in zip(found, out.alternatives))
    if options.slide:
        out = slide(model, data, out, pool, g, grid, options)
    if options.kink_hops:
        out = kink_hops(model, data, out, options)
    out = dataclasses.replace(kink_polish(model, data, out, options), alternatives=pool)
    return escalate(model, data, out, options) if options.escalate else out
