"""Close or lopsided sources on a ring: the fast K = 2, 3 fit escalated to the exact optimum.

With the clipped cosine two sources seen by the same sub-sensors give one
cosine, so close pairs have likelihoods with many cells and shallow optima.
On a 30-ring the fast search missed the global optimum (found by
:func:`olsbayes.ml.exact.fit_exact`) in 1.6-3.6 % of K = 2 fits of pairs 0.4-8
spacings apart (up to a third below one spacing; sigma 1e-4..1e-2, 12,000
fits) and in 158 of 2,400 K = 3 fits with a pair 0.4-3 spacings apart (8-31 %
at <= 1 spacing); the ML error over resolvable placements at 1.25 spacings,
sigma = 1e-4, was 0.078 rad instead of the CRLB's 8.3e-5 that the global
optimum reaches.  Every miss had two fitted sources closer than 4 spacings or
an intensity below 1 % of the largest, so exactly those fits are refitted by
enumeration (~0.02-0.19 ms at K = 2 and ~0.2-1.1 ms at K = 3 per fit, batched or
alone); well-separated scenes (Fig. 3, the benchmark's K = 3) are not touched.
"""

from __future__ import annotations

import numpy as np

from ..geometry import Ring
from ..model import Model
from ..sensitivity import is_clipped_cosine
from .batch import LMOutcome

__all__ = ["exact_pairs", "exact_applies", "CLOSE_SPACINGS", "WEAK_RATIO", "SOURCES"]

#: Fitted sources closer than this many sensor spacings (2 pi / N) are escalated.
CLOSE_SPACINGS = 4.0

#: ... and so are fits whose weakest intensity is below this fraction of the strongest.
WEAK_RATIO = 0.01


#: Numbers of sources escalated (the enumeration costs, batched | alone, ~0.02 | 0.19 ms
#: at K = 2, ~0.21 | 1.1 ms at K = 3, ~2.6 | 15 ms at K = 4 on a 30-ring).
SOURCES = (2, 3)


def exact_applies(model: Model, k: int) -> bool:
    """Whether K-source fits of this model are escalated (ring, clipped cosine, K in SOURCES)."""
    law = model.sensitivity
    return (k in SOURCES and isinstance(model.array, Ring)
            and is_clipped_cosine(law))


def exact_pairs(model: Model, data: np.ndarray, out: LMOutcome) -> LMOutcome:
    """Refit close or lopsided K = 2, 3 ring fits exactly; keep whichever is better.

    ``out`` holds fits (T, 2K) of ``data`` (T, N).  Other models and K pass
    through unchanged.  Evaluation counts are not changed (the enumeration
    solves linear least-squares problems, it does not evaluate the model).
    """
    k = out.x.shape[1] // 2
    if not exact_applies(model, k):
        return out
    from . import _checks_kernel
    from .exact import fit_exact

    x = out.x
    close = CLOSE_SPACINGS * 2 * np.pi / model.n_sensors
    rows = np.flatnonzero(_checks_kernel.close_or_weak(x, close, WEAK_RATIO))
    if rows.size == 0:
        return out
    ex = np.atleast_2d(fit_exact(model, data[rows], k, count_feasible=False).params)
    chi2 = np.sum((data[rows] - model.response(ex)) ** 2, axis=-1)
    better = chi2 < out.chi2[rows] * (1 - 1e-12)
    sel = rows[better]
    new_x, new_chi2 = x.copy(), out.chi2.copy()
    conv, stalled = out.converged.copy(), out.stalled.copy()
    new_x[sel], new_chi2[sel], conv[sel], stalled[sel] = ex[better], chi2[better], True, False
    return LMOutcome(new_x, new_chi2, conv, out.n_evaluations, stalled, out.alternatives)
