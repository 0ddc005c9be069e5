"""Numpy reference of the fast fit's grid search (:mod:`olsbayes.ml.fast.search`).

Two stages, both conditional least squares on the atom dictionary G (M, N):
orthogonal matching pursuit (pick the atom that best explains the data, project
it out, repeat K times), then alternating projection (re-choose each source's
atom given the other K - 1, until a sweep changes nothing); runner-up positions
of each source; and the best K-tuple of each coarse subset
(:func:`tuples_numpy.tuple_search`).  Vectorised over trials with numpy; the
tests check the compiled search against it.
"""

from __future__ import annotations

import numpy as np

from olsbayes.ml.atoms import NEIGHBOUR
from olsbayes.ml.fast.options import FastOptions
from olsbayes.ml.fast.tuples import TuplePlan, tuple_plans

from .tuples_numpy import tuple_search

__all__ = ["grid_search_numpy"]

_CHUNK = 512


def _scores(g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Residual-sum-of-squares drop of every atom given bases q, shape (T, M).

    g (M, N), gnorm2 (M,), s (T, N), q (T, N, k) orthonormal columns (k may be 0).
    """
    num = s @ g.T  # (T, M)
    den = np.broadcast_to(gnorm2, num.shape).copy()
    t, n, k = q.shape
    if k:
        qt = np.swapaxes(q, 1, 2)  # (T, k, N)
        cg = (qt.reshape(t * k, n) @ g.T).reshape(t, k, -1)  # (T, k, M), one GEMM
        cs = (qt @ s[:, :, None])[..., 0]  # (T, k)
        for j in range(k):
            num -= cg[:, j] * cs[:, j, None]
            den -= np.square(cg[:, j])
    ok = (num > 0) & (den > 1e-8 * gnorm2)
    return np.where(ok, num**2 / np.where(ok, den, 1.0), -np.inf)


def _basis(g: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Orthonormal basis (T, N, k) of the atoms idx (T, k)."""
    if idx.shape[1] == 0:
        return np.zeros((idx.shape[0], g.shape[1], 0))
    a = np.swapaxes(g[idx], 1, 2)  # (T, N, k)
    q, _ = np.linalg.qr(a)
    return q


def _pursuit(
    g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Orthogonal matching pursuit: K atoms chosen one at a time, shape (T, K).

    Also returns the scores (T, M) of the last choice (given the first K - 1 atoms).
    """
    idx = np.zeros((s.shape[0], 0), dtype=np.int64)
    for _ in range(k):
        sc = _scores(g, gnorm2, s, _basis(g, idx))
        idx = np.column_stack([idx, np.argmax(sc, axis=1)])
    return idx, sc


def _alternate(
    g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, idx: np.ndarray, max_sweeps: int
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Alternating projection from ``idx`` (T, K): re-choose each atom given the rest.

    Returns the atoms and, when the last sweep changed nothing, that sweep's
    conditional scores of each source given the others (K arrays (T, M)), else None.
    """
    idx = idx.copy()
    t, k = idx.shape
    rows = np.arange(t)
    for _ in range(max_sweeps if k > 1 else 0):
        changed = np.zeros(t, bool)
        scores = []
        for j in range(k):
            others = np.delete(idx, j, axis=1)
            sc = _scores(g, gnorm2, s, _basis(g, others))
            scores.append(sc)
            best = np.argmax(sc, axis=1)
            better = sc[rows, best] > sc[rows, idx[:, j]] * (1 + 1e-12)
            changed |= better
            idx[:, j] = np.where(better, best, idx[:, j])
        if not changed.any():
            return idx, scores
    return idx, None


def _alternatives(
    g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, idx: np.ndarray, n_alt: int,
    scores: list[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Runner-up positions of each source given the others, ``K * n_alt`` sets (T, K).

    For source j the conditional scores are scanned for the next-best atoms
    outside the neighbourhood (normalised-atom correlation > ``NEIGHBOUR``) of
    atoms already taken -- distinct basins of a weak source, which the
    conditional optimum on the grid may miss after refinement.  ``scores``: the
    conditional scores of each source given the others at ``idx``, if known
    (they are overwritten).
    """
    unit = g / np.sqrt(np.maximum(gnorm2, 1e-300))[:, None]
    out = []
    for j in range(idx.shape[1]):
        if scores is None:
            sc = _scores(g, gnorm2, s, _basis(g, np.delete(idx, j, axis=1)))
        else:
            sc = scores[j]
        taken = idx[:, j]
        for _ in range(n_alt):
            sc[unit[taken] @ unit.T > NEIGHBOUR] = -np.inf
            taken = np.argmax(sc, axis=1)
            ok = np.isfinite(sc[np.arange(sc.shape[0]), taken])
            alt = idx.copy()
            alt[:, j] = np.where(ok, taken, idx[:, j])
            out.append(alt)
    return out


def _search_chunk(
    g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, k: int, max_sweeps: int,
    plans: list[TuplePlan], n_alt: int, distinct: bool = False, pursuit: bool = True,
) -> np.ndarray:
    """Candidate K-atom sets (T, C, K): pursuit + alternating projection, runner-up
    positions of each source (if ``pursuit``), the best tuple of each coarse subset
    and, with ``distinct``, each subset's best tuple of a second mode."""
    cands = []
    if pursuit:
        first, last = _pursuit(g, gnorm2, s, k)
        base, scores = _alternate(g, gnorm2, s, first, max_sweeps)
        if k == 1:  # no sweeps; the scores of the single source given no others
            scores = [last]
        cands = [base] + _alternatives(g, gnorm2, s, base, n_alt, scores)
    found = [tuple_search(plan, s, distinct) for plan in plans]
    if distinct:
        cands += [f[0] for f in found] + [f[1] for f in found]
    else:
        cands += found
    return np.stack(cands, axis=1)


def _intensities(
    g: np.ndarray, s: np.ndarray, idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intensities (T, C, K), clipped at 0, and residual sums of squares."""
    a = g[idx]  # (T, C, K, N)
    ata = a @ np.swapaxes(a, -1, -2)
    tr = np.trace(ata, axis1=-2, axis2=-1)[..., None, None]
    ridge = 1e-10 * tr * np.eye(idx.shape[-1]) + 1e-300
    rhs = np.einsum("tckn,tn->tck", a, s)
    coef = np.linalg.solve(ata + ridge, rhs[..., None])[..., 0]
    rss = np.einsum("tn,tn->t", s, s)[:, None] - np.einsum("tck,tck->tc", rhs, coef)
    return np.maximum(coef, 0.0), rss




def grid_search_numpy(g: np.ndarray, data: np.ndarray, k: int,
                      options: FastOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`olsbayes.ml.fast.search.grid_search` in numpy, vectorised over trials.

    Same arguments, stages, scores (to rounding: Householder QR instead of
    Gram-Schmidt) and tie-breaking (first maximum) as the compiled search.
    """
    gnorm2 = np.einsum("mn,mn->m", g, g)
    dtype = np.float32 if options.single_precision else np.float64
    plans = tuple_plans(g, k, options.n_coarse, options.tuple_budget, dtype) if k >= 2 else []
    parts = [
        _search_chunk(g, gnorm2, data[i : i + _CHUNK], k, options.max_sweeps, plans,
                      options.runners_up, options.distinct_modes, options.pursuit or not plans)
        for i in range(0, data.shape[0], _CHUNK)
    ]
    idx = np.concatenate(parts, axis=0)
    return (idx, *_intensities(g, data, idx))


def search_options(k: int, **changes) -> FastOptions:
    """The search settings the tests use: 3 coarse subsets of 5,000 tuples, 2 runners-up,
    pursuit on, no second modes, float32 tuple scores at K = 4 (``changes`` override)."""
    base = dict(n_coarse=3, tuple_budget=5_000, runners_up=2, distinct_modes=False,
                pursuit=True, single_precision=k == 4)
    return FastOptions(**{**base, **changes})


def plans(g: np.ndarray, k: int, n_sets: int, budget: int = 5_000,
          dtype: type | None = None) -> list[TuplePlan]:
    """:func:`tuple_plans` with the tests' defaults (float32 at K = 4, else float64)."""
    return tuple_plans(g, k, n_sets, budget, dtype or (np.float32 if k == 4 else np.float64))
