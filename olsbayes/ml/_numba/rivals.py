"""Compiled (numba) rival optima of angle fits: twin of :mod:`olsbayes.ml.rivals`.

For one data vector the numpy version is a dozen small numpy calls; compiled it
is one.  Same rule and results: angles wrapped to (-pi, pi], sources matched by
the permutation minimising the summed squared angle error
(:mod:`olsbayes.exchange`), ties to the first permutation.
"""

from __future__ import annotations

import numba
import numpy as np

from .circular import wrap

__all__ = ["angle_rival_gap"]


@numba.njit(cache=True)
def _distinct(cand, best, std, perms, n_std):  # pragma: no cover - compiled
    """Whether the best-matched source angles of ``cand`` and ``best`` differ somewhere.

    True when a matched pair differs by more than n_std std (flat [angle, I] layout).
    """
    k = perms.shape[1]
    cost_min, arg = np.inf, 0
    for p in range(perms.shape[0]):
        cost = 0.0
        for j in range(k):
            d = wrap(cand[2 * perms[p, j]] - best[2 * j])
            cost += d * d
        if cost < cost_min:
            cost_min, arg = cost, p
    for j in range(k):
        if abs(wrap(cand[2 * perms[arg, j]] - best[2 * j])) > n_std * std[2 * j]:
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
