"""Close or lopsided sources on a ring: fast fits escalated to the exact optimum.

With the clipped cosine two sources seen by the same sub-sensors give one
cosine, so close pairs have likelihoods with many cells and shallow optima, and
the grid search plus local refinement can stop in one that is not the global
optimum -- at separations below a few sensor spacings often, and with a weak
source beside a strong one.  The fits where this happened all had two fitted
sources closer than a few spacings or an intensity below about 1 % of the
largest, so exactly those fits are refitted by enumerating the likelihood's
linear cells (:mod:`olsbayes.ml.exact`); well-separated scenes are not touched.
"""

from __future__ import annotations

import numpy as np

from ...model import Model
from ..exact import enumerate_optimum
from ..outcome import FitOutcome
from .options import FastOptions
from .refine import _improves

__all__ = ["escalate"]


def escalate(model: Model, data: np.ndarray, out: FitOutcome, opts: FastOptions) -> FitOutcome:
    """Refit close or lopsided ring fits exactly; keep whichever is better.

    ``out`` holds fits (T, 2K) of ``data`` (T, N) of a ring with the clipped
    cosine.  A fit is escalated when two of its sources are closer than
    ``opts.close_spacings`` sensor spacings (2 pi / N) or its weakest intensity is
    at most ``opts.weak_ratio`` times the strongest, unless it fits the readings
    exactly (chi^2 = 0: nothing can fit better).  Evaluation counts are not
    changed (the enumeration solves linear least-squares problems, it does not
    evaluate the model).
    """
    from .._numba import escalate as compiled  # numba is imported on first use

    k = out.x.shape[1] // 2
    x = out.x
    close = opts.close_spacings * 2 * np.pi / model.n_sensors
    # a fit with chi^2 = 0 (all-zero readings, say) is already a global optimum
    rows = np.flatnonzero(compiled.close_or_weak(x, close, opts.weak_ratio) & (out.chi2 > 0))
    if rows.size == 0:
        return out
    ex = enumerate_optimum(model, data[rows], k).params
    chi2 = np.sum((data[rows] - model.response(ex)) ** 2, axis=-1)
    better = _improves(chi2, out.chi2[rows])
    sel = rows[better]
    new_x, new_chi2 = x.copy(), out.chi2.copy()
    conv, stalled = out.converged.copy(), out.stalled.copy()
    new_x[sel], new_chi2[sel], conv[sel], stalled[sel] = ex[better], chi2[better], True, False
    return FitOutcome(new_x, new_chi2, conv, out.n_evaluations, stalled, out.alternatives)
