"""Compiled (numba) post-fit checks of angle fits: close/weak sources, rival optima.

For a single data vector the numpy versions (:func:`olsbayes.ml.pairs.exact_pairs`'
selection and :func:`olsbayes.ml.rivals.rival_gap`) are ~15-20 small numpy calls
each, ~35 us together against a ~300 us fit; compiled they are one call each.
Same rules and results (angles wrapped to (-pi, pi], sources matched by the
permutation minimising the summed squared angle error, as in
:func:`olsbayes.exchange.estimation_errors`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["close_or_weak", "angle_rival_gap"]

_TWO_PI = 2.0 * np.pi


@numba.njit(cache=True)
def _wrap(a):  # pragma: no cover - compiled
    """Angle wrapped to (-pi, pi] (circular.wrap_angle)."""
    w = a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)
    return math.pi if w == -math.pi else w


@numba.njit(cache=True)
def close_or_weak(x, close, weak):  # pragma: no cover - compiled
    """Rows of x (T, 2K) with two angles closer than ``close`` rad or an intensity
    <= ``weak`` times the largest: bool (T,)."""
    t, k = x.shape[0], x.shape[1] // 2
    out = np.zeros(t, dtype=np.bool_)
    for i in range(t):
        lo, hi = np.inf, 0.0
        for a in range(k):
            lo, hi = min(lo, x[i, 2 * a + 1]), max(hi, x[i, 2 * a + 1])
            for b in range(a + 1, k):
                if abs(_wrap(x[i, 2 * a] - x[i, 2 * b])) < close:
                    out[i] = True
        if lo <= weak * hi:
            out[i] = True
    return out


@numba.njit(cache=True)
def _distinct(cand, best, std, perms, n_std):  # pragma: no cover - compiled
    """Whether the best-matched source angles of ``cand`` differ from ``best``'s by
    more than n_std std somewhere (flat [angle, I] layout)."""
    k = perms.shape[1]
    cost_min, arg = np.inf, 0
    for p in range(perms.shape[0]):
        cost = 0.0
        for j in range(k):
            d = _wrap(cand[2 * perms[p, j]] - best[2 * j])
            cost += d * d
        if cost < cost_min:
            cost_min, arg = cost, p
    for j in range(k):
        if abs(_wrap(cand[2 * perms[arg, j]] - best[2 * j])) > n_std * std[2 * j]:
            return True
    return False


@numba.njit(cache=True)
def angle_rival_gap(x, chi2, alt_x, alt_chi2, std, inv_two_s2, tie, top, perms,
                    n_std):  # pragma: no cover - compiled
    """rivals.rival_gap for angle models (one angle per source), shape (T,)."""
    t, c = alt_chi2.shape
    out = np.full(t, np.inf)
    for i in range(t):
        for j in range(c):
            gap = (alt_chi2[i, j] - chi2[i]) * inv_two_s2
            if gap > tie and gap < top and gap < out[i]:
                if _distinct(alt_x[i, j], x[i], std[i], perms, n_std):
                    out[i] = gap
    return out
