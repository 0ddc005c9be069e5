"""Mirrored optima of near-antipodal ring pairs (:mod:`olsbayes.antipodal`).

A pair of ring sources within a couple of sensor spacings of antipodal may have
a *mirrored* optimum -- each source moved to the antipode of the other -- that
fits as well as the estimate (:mod:`olsbayes.antipodal` gives the reason).  The
fit's starts rarely reach it, so :func:`mirror_gap` refines the mirrored
configurations of every estimate with such pairs and reports how far below the
estimate's log-likelihood the best distinct one lies: small gaps mean the ML
estimate is one of several equally good answers and its Fisher covariance
describes only that one.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..antipodal import ANTIPODAL_SPACINGS, antipodal_pairs, mirror_pair, pair_offsets
from ..exchange import estimation_errors
from ..model import Model
from .rivals import DISTINCT_STD

__all__ = ["mirror_candidates", "mirror_gap"]

#: Pairs mirrored at most (2**4 - 1 combinations per estimate).
MAX_PAIRS = 4


def mirror_candidates(model: Model, x: np.ndarray) -> np.ndarray:
    """Every mirrored configuration (C, P) of one estimate x (P,); C = 0 without pairs."""
    pairs = [(i, j) for i, j, _ in antipodal_pairs(model, x, within=ANTIPODAL_SPACINGS)]
    out = []
    for r in range(1, min(len(pairs), MAX_PAIRS) + 1):
        for subset in itertools.combinations(pairs[:MAX_PAIRS], r):
            used = [s for p in subset for s in p]
            if len(set(used)) < len(used):
                continue
            y = x
            for i, j in subset:
                y = mirror_pair(y, i, j, model.n_loc + 1)
            out.append(y)
    return np.array(out).reshape(len(out), x.size)


def mirror_gap(model: Model, data: np.ndarray, x: np.ndarray, ll: np.ndarray,
               std: np.ndarray) -> np.ndarray:
    """Log-likelihood of each estimate minus that of its best distinct mirrored optimum.

    Parameters
    ----------
    model : Model
    data : ndarray (T, N)
    x : ndarray (T, P)
        Estimates.
    ll : ndarray (T,)
        Their log-likelihoods.
    std : ndarray (T, P)
        Fisher standard deviations at the estimates.

    Returns
    -------
    ndarray (T,)
        inf where no estimate has a near-antipodal pair or no mirrored
        configuration refines to a distinct optimum (locations more than
        :data:`~olsbayes.ml.rivals.DISTINCT_STD` std apart); may be negative
        (the mirrored optimum fits better).
    """
    from ..sensitivity import is_clipped_cosine
    from .lm import refine_batch

    out = np.full(x.shape[0], np.inf)
    if model.kind != "angle":
        return out
    # only estimates with a pair that near antipodal have mirrored configurations
    near = np.flatnonzero(np.any(np.abs(pair_offsets(model, x)) < ANTIPODAL_SPACINGS, axis=1))
    cand = [mirror_candidates(model, x[r]) for r in near]
    rows = np.repeat(near, [c.shape[0] for c in cand])
    if rows.size == 0:
        return out
    fit = refine_batch(model, data[rows], np.concatenate(cand),
                       kinks=is_clipped_cosine(model.sensitivity))
    gap = ll[rows] - model.log_likelihood(fit.x, data[rows])
    loc = np.ones(x.shape[1], dtype=bool)
    loc[model.n_loc :: model.n_loc + 1] = False
    err = estimation_errors(model, fit.x, x[rows])
    distinct = np.any(np.abs(err[:, loc]) > DISTINCT_STD * std[rows][:, loc], axis=-1)
    np.minimum.at(out, rows[distinct], gap[distinct])
    return out
