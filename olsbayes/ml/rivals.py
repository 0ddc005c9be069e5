"""Distinct local optima that fit almost as well as an ML estimate (multimodality).

The fast search refines many candidate starts and the multistart baseline many
random ones; besides the winner they reach other local optima.  One whose
source locations differ from the estimate's by more than :data:`DISTINCT_STD`
Fisher standard deviations (after matching sources) and whose log-likelihood is
within a few units of the estimate's is a rival mode: the likelihood is
multimodal there, the ML estimate may jump between the modes from one noise
draw to the next, and the Fisher covariance (the local CRLB) understates the
uncertainty.  On random well-separated K = 4 scenes on a 30-ring at sigma =
0.01, every fit far (> 5 CRLB std) from the truth had such a rival within 3
log-likelihood units, and a few per cent of the other fits too.  A rival found
is a real local optimum; none found does not prove there is none (the search
reports what its starts reached).
"""

from __future__ import annotations

import numpy as np

from ..exchange import estimation_errors, permutations
from ..model import Model

__all__ = ["rival_gap", "rival_gap_numpy", "DISTINCT_STD", "RIVAL_WARN", "RIVAL_RANGE", "TIE"]

#: A location differing by more than this many Fisher std makes an optimum distinct.
DISTINCT_STD = 3.0

#: fit_ml warns (MultimodalWarning) when a rival is within this log-likelihood.
RIVAL_WARN = 3.0

#: The compiled rule for angle and lon/lat fits matches sources over all K! permutations: used
#: up to this K.  Beyond it the numpy rule matches them (by
#: :func:`olsbayes.exchange.best_permutation`: exhaustive up to
#: :data:`~olsbayes.exchange.MAX_EXHAUSTIVE` sources, the Hungarian algorithm beyond).
MAX_SOURCES = 6

#: Optima further below the estimate than this (log-likelihood units) are ignored.
RIVAL_RANGE = 20.0

#: Optima within this (log-likelihood units) of the estimate count as the estimate:
#: an exact tie with a distinct optimum is a null event under noise.
TIE = 1e-5


def rival_gap(
    model: Model, x: np.ndarray, chi2: np.ndarray, alternatives: tuple | None,
    std: np.ndarray,
) -> np.ndarray:
    """Log-likelihood of each estimate minus that of its best distinct rival optimum.

    Parameters
    ----------
    model : Model
    x : ndarray, shape (T, P)
        Estimates, canonical order.
    chi2 : ndarray, shape (T,)
        Their residual sums of squares.
    alternatives : (ndarray (T, C, P), ndarray (T, C)) or None
        Other optima reached per trial and their residual sums of squares (inf:
        no optimum in that slot).  None: not assessed.
    std : ndarray, shape (T, P)
        Fisher standard deviations at the estimates (inf: unidentified).

    Returns
    -------
    ndarray, shape (T,)
        >= 0; inf where no distinct optimum was reached within
        :data:`RIVAL_RANGE`, NaN where not assessed (no alternatives).
    """
    t = x.shape[0]
    k = model.n_sources_of(x)
    if alternatives is None:
        return np.full(t, np.nan)
    alt_x, alt_chi2 = alternatives
    if model.kind != "position" and k <= MAX_SOURCES:  # compiled, same rule
        from ._numba import rivals  # numba is imported on first use

        return rivals.far_rival_gap(x, chi2, alt_x, alt_chi2, std, 0.5 / model.sigma**2, TIE,
                                    RIVAL_RANGE, permutations(k), DISTINCT_STD, model.n_loc + 1)
    return rival_gap_numpy(model, x, chi2, alt_x, alt_chi2, std)


def rival_gap_numpy(
    model: Model, x: np.ndarray, chi2: np.ndarray, alt_x: np.ndarray, alt_chi2: np.ndarray,
    std: np.ndarray,
) -> np.ndarray:
    """:func:`rival_gap` in numpy (any model; the reference of the compiled one).

    Candidates are matched nearest first (by log-likelihood), in blocks of
    doubling size, and a trial is done at its first distinct one: the same minimum
    as matching all of them, in a few matchings where the nearest optimum is
    already distinct (many sources, hundreds of candidates).
    """
    t = x.shape[0]
    gap = (alt_chi2 - chi2[:, None]) / (2.0 * model.sigma**2)  # (T, C)
    # inf and NaN compare False; a gap below TIE is the estimate itself (a start that
    # converged to it, or stopped within the dedupe distance of it)
    gap = np.where((gap > TIE) & (gap < RIVAL_RANGE), gap, np.inf)
    order = np.argsort(gap, axis=1, kind="stable")
    count = np.isfinite(gap).sum(axis=1)
    out = np.full(t, np.inf)
    d1 = model.n_loc + 1
    loc = np.ones(x.shape[1], dtype=bool)
    loc[d1 - 1 :: d1] = False  # intensities are linear given the locations
    todo, lo, size = np.flatnonzero(count), 0, 4
    while todo.size:
        cols = order[todo, lo:lo + size]
        rows = np.repeat(todo, cols.shape[1])
        cols = cols.ravel()
        live = np.isfinite(gap[rows, cols])
        rows, cols = rows[live], cols[live]
        err = estimation_errors(model, alt_x[rows, cols], x[rows])  # (n, P)
        distinct = np.any(np.abs(err[:, loc]) > DISTINCT_STD * std[rows][:, loc], axis=-1)
        np.minimum.at(out, rows[distinct], gap[rows[distinct], cols[distinct]])
        lo, size = lo + size, 2 * size
        todo = todo[np.isinf(out[todo]) & (count[todo] > lo)]
    return out
