"""Compiled (numba) choice of the fits to escalate: twin of :mod:`olsbayes.ml.fast.escalate`."""

from __future__ import annotations

import numba
import numpy as np

from .circular import wrap

__all__ = ["close_or_weak"]


@numba.njit(cache=True)
def close_or_weak(x, close, weak):  # pragma: no cover - compiled
    """Rows of x (T, 2K) with two close angles or a weak intensity: bool (T,).

    Close: two angles closer than ``close`` rad; weak: an intensity <= ``weak`` times
    the largest.
    """
    t, k = x.shape[0], x.shape[1] // 2
    out = np.zeros(t, dtype=np.bool_)
    for i in range(t):
        lo, hi = np.inf, 0.0
        for a in range(k):
            lo, hi = min(lo, x[i, 2 * a + 1]), max(hi, x[i, 2 * a + 1])
            for b in range(a + 1, k):
                if abs(wrap(x[i, 2 * a] - x[i, 2 * b])) < close:
                    out[i] = True
        if lo <= weak * hi:
            out[i] = True
    return out
