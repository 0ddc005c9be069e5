"""Compiled (numba) doubts about Gaussian errors: twin of :mod:`olsbayes.resolution`.

The per-row tests of :func:`olsbayes.resolution.gaussian_doubts` and of the fit's
missing standard errors that need only the estimates and their covariances, in
one pass: a single fit's checks are a few dozen numbers, where numpy's per-call
cost would be most of the work.
"""

from __future__ import annotations

import numba
import numpy as np

from . import kernel_array

__all__ = ["covariance_doubts"]


@numba.njit(cache=True)
def _doubt_rows(x, cov, width, weak_sds, finite, weak, no_std):  # pragma: no cover
    """Per row of x (T, P) and cov (T, P, P), the flags of :func:`covariance_doubts`.

    Finite: every entry finite and every variance > 0; weak: an intensity below
    ``weak_sds`` of its sd (a NaN sd counts); no_std: a non-finite sd.
    """
    t, p = x.shape
    for i in range(t):
        ok, low, bad = True, False, False
        for a in range(p):
            for b in range(p):
                ok = ok and np.isfinite(cov[i, a, b])
            v = cov[i, a, a]
            ok = ok and v > 0.0
            sd = np.sqrt(v) if v >= 0.0 else np.nan  # numpy's sqrt: NaN below 0
            bad = bad or not np.isfinite(sd)
            if a % width == width - 1:
                low = low or not x[i, a] >= weak_sds * sd
        finite[i], weak[i], no_std[i] = ok, low, bad


def covariance_doubts(x: np.ndarray, cov: np.ndarray, width: int, weak_sds: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of estimates x (T, P) with covariances cov (T, P, P): three bool (T,).

    ``finite``: every entry of cov finite and every variance > 0 (the rows whose
    errors :func:`~olsbayes.resolution.gaussian_doubts` judges); ``weak``: some
    intensity (every ``width``-th parameter) not >= ``weak_sds`` times its sd
    (:func:`~olsbayes.resolution.weak_sources`, before the ``finite`` mask);
    ``no_std``: some sd sqrt(diag cov) not finite.
    """
    xx, cc = kernel_array(x, np.float64), kernel_array(cov, np.float64)
    t = xx.shape[0]
    finite, weak, no_std = np.empty(t, np.bool_), np.empty(t, np.bool_), np.empty(t, np.bool_)
    _doubt_rows(xx, cc, int(width), float(weak_sds), finite, weak, no_std)
    return finite, weak, no_std
