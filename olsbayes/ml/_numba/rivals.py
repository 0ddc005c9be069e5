"""Compiled (numba) rival optima of distant-source fits: twin of :mod:`olsbayes.ml.rivals`.

For one data vector the numpy version is a dozen small numpy calls; compiled it
is one.  Same rule and results for angle (ring) and lon/lat (sphere) fits:
longitudes and angles wrapped to (-pi, pi], sources matched by the permutation
minimising the summed squared location error (:mod:`olsbayes.exchange`: each
pair's coordinates summed in order, the pairs in source order), ties to the
first permutation.
"""

from __future__ import annotations

import numba
import numpy as np

from .circular import wrap

__all__ = ["far_rival_gap"]


@numba.njit(cache=True)
def _error(cand, best, i, j, c, d1):  # pragma: no cover - compiled
    """Location coordinate c of candidate source i minus best source j (the first wrapped)."""
    d = cand[d1 * i + c] - best[d1 * j + c]
    return wrap(d) if c == 0 else d


@numba.njit(cache=True)
def _distinct(cand, best, std, perms, n_std, d1):  # pragma: no cover - compiled
    """Whether the best-matched source locations of ``cand`` and ``best`` differ somewhere.

    True when a matched coordinate differs by more than n_std std (flat layout of
    d1 = location coordinates + 1 per source).
    """
    k = perms.shape[1]
    cost_min, arg = np.inf, 0
    for p in range(perms.shape[0]):
        cost = 0.0
        for j in range(k):
            pair = 0.0  # 0 + d^2 is d^2: the same sums as numpy's, coordinate by coordinate
            for c in range(d1 - 1):
                d = _error(cand, best, perms[p, j], j, c, d1)
                pair += d * d
            cost += pair
        if cost < cost_min:
            cost_min, arg = cost, p
    for j in range(k):
        for c in range(d1 - 1):
            if abs(_error(cand, best, perms[arg, j], j, c, d1)) > n_std * std[d1 * j + c]:
                return True
    return False


@numba.njit(cache=True)
def far_rival_gap(x, chi2, alt_x, alt_chi2, std, inv_two_s2, tie, top, perms, n_std,
                  d1):  # pragma: no cover - compiled
    """rivals.rival_gap for distant sources (d1 = 2: angles, 3: lon/lat), shape (T,)."""
    t, c = alt_chi2.shape
    out = np.full(t, np.inf)
    for i in range(t):
        for j in range(c):
            gap = (alt_chi2[i, j] - chi2[i]) * inv_two_s2
            if gap > tie and gap < top and gap < out[i]:
                if _distinct(alt_x[i, j], x[i], std[i], perms, n_std, d1):
                    out[i] = gap
    return out
