"""The fast, polynomial-time ML estimator: grid search + joint LM refinement.

Pipeline for a batch of T data vectors (all stages vectorised over trials):

1. :func:`~olsbayes.ml.search.grid_search` -- matching pursuit then alternating
   projection on a dictionary of unit-intensity atoms (cost O(T M N K^2) per
   sweep, M grid points): a global search that is polynomial in K.
2. :func:`~olsbayes.ml.batch.refine_batch` -- joint bounded Levenberg–Marquardt
   on all K (d + 1) parameters with the analytic Jacobian.
3. A few deterministic perturbed restarts: every source location is shifted by
   a fixed sign pattern of size ``restart_scale`` grid steps, refined again, and
   the best likelihood per trial kept.  They remove the shallow false minima a
   source creates when a sub-sensor lies about 90 deg from it (the kink of the
   clipped cosine).  Being deterministic, a batch fit equals a loop of single fits.
"""

from __future__ import annotations

import numpy as np

from ..model import Model
from .batch import LMOutcome, refine_batch
from .grid import atoms, grid_step
from .search import grid_search

__all__ = ["fit_fast", "restart_patterns"]


def restart_patterns(k: int, d: int, n: int) -> np.ndarray:
    """``n`` deterministic sign patterns for the restarts, shape (n, K, d).

    The first four are all +1, all -1, alternating +-, alternating -+ (over the
    flattened K*d location coordinates); further ones cycle through a fixed
    Hadamard-like sequence.
    """
    m = k * d
    j = np.arange(m)
    base = [np.ones(m), -np.ones(m), (-1.0) ** j, -((-1.0) ** j)]
    extra = 0
    while len(base) < n:
        extra += 1
        base.append(np.where(((j + 1) >> (extra - 1)) & 1, 1.0, -1.0) * (-1.0) ** extra)
    return np.array(base[:n]).reshape(n, k, d)


def _best(a: LMOutcome, b: LMOutcome) -> LMOutcome:
    better = b.chi2 < a.chi2 * (1 - 1e-12)
    return LMOutcome(
        x=np.where(better[:, None], b.x, a.x),
        chi2=np.where(better, b.chi2, a.chi2),
        converged=np.where(better, b.converged, a.converged),
        n_evaluations=a.n_evaluations + b.n_evaluations,
    )


def fit_fast(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    grid: np.ndarray,
    *,
    n_restarts: int = 4,
    restart_scale: float = 6.0,
    n_coarse: int = 3,
    max_iter: int = 100,
) -> LMOutcome:
    """Fast ML fits of a batch ``data`` (T, N); returns the raw (T, P) outcome."""
    k, d = n_sources, model.n_loc
    t = data.shape[0]
    g = atoms(model, grid)
    idx, inten = grid_search(g, data, k, n_coarse=n_coarse)  # (T, C, K)
    c = idx.shape[1]
    x0 = np.concatenate([grid[idx], inten[..., None]], axis=-1).reshape(t * c, -1)
    cand = refine_batch(model, np.repeat(data, c, axis=0), x0, max_iter=max_iter)
    chi2 = cand.chi2.reshape(t, c)
    pick = np.arange(t) * c + np.argmin(chi2, axis=1)
    out = LMOutcome(
        x=cand.x[pick], chi2=cand.chi2[pick], converged=cand.converged[pick],
        n_evaluations=cand.n_evaluations.reshape(t, c).sum(axis=1),
    )
    if n_restarts:
        delta = restart_scale * grid_step(model, grid)
        for pat in restart_patterns(k, d, n_restarts):
            x = out.x.reshape(t, k, d + 1).copy()
            x[:, :, :d] += pat * delta
            out = _best(out, refine_batch(model, data, x.reshape(t, -1), max_iter=max_iter))
    return out
