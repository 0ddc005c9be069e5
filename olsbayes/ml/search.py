"""Polynomial-time global search on a grid of atoms, batched over trials.

Two stages, both conditional least squares on the atom dictionary G (M, N):

1. *Orthogonal matching pursuit*: pick the atom that best explains the data
   (the matched filter ``G @ s`` normalised), project it out, repeat K times.
2. *Alternating projection* (Ziskind & Wax, 1988): cycle over the K sources,
   re-choosing each one's atom given the other K-1 atoms, whose intensities are
   refitted jointly; stop when a sweep changes nothing.  Each move cannot
   increase the residual, so the sweeps separate sources that greedy peel-off
   merged (the main failure of pure matched filtering for K >= 3).

The score of atom g given the span Q of the other atoms is the drop in the
residual sum of squares, ``(g' P s)^2 / (g' P g)`` with P the projector onto
the orthogonal complement of Q, kept only where ``g' P s > 0`` (a positive
intensity).  Cost per move: O(T M N K).
"""

from __future__ import annotations

import weakref

import numpy as np

from .tuples import NEIGHBOUR as _NEIGHBOUR
from .tuples import TUPLE_BUDGET, TuplePlan, tuple_plans, tuple_search

__all__ = ["grid_search", "grid_search_numpy"]

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
    outside the neighbourhood (normalised-atom correlation > ``_NEIGHBOUR``) of
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
            sc[unit[taken] @ unit.T > _NEIGHBOUR] = -np.inf
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


def _frozen_view(a: np.ndarray, dtype: type = float) -> np.ndarray:
    """A C-contiguous read-only view (one array type, so one compiled signature)."""
    v = np.ascontiguousarray(a, dtype=dtype).view()
    v.flags.writeable = False
    return v


_VIEWS: dict = {}  # id -> (weakref, views) of read-only atom arrays and tuple plans


def _memo(obj: object, make, readonly: bool = True) -> tuple:
    """``make(obj)``, memoised for a live read-only object (the cached atoms, plans)."""
    hit = _VIEWS.get(id(obj))
    if hit is not None and hit[0]() is obj:
        return hit[1]
    out = make(obj)
    if readonly:
        if len(_VIEWS) >= 64:
            _VIEWS.clear()
        _VIEWS[id(obj)] = (weakref.ref(obj), out)
    return out


#: Largest M^2 N for which the atoms' basins (neighbour lists) are precomputed.
_NEIGHBOUR_WORK = 50_000_000
#: Largest M for which the atoms' Gram matrix (M^2 doubles) serves the search's projections.
_GRAM_ATOMS = 1024


def _atom_views(g: np.ndarray) -> tuple[np.ndarray, ...]:
    """Read-only views of the atoms, their Gram matrix (empty when M > :data:`_GRAM_ATOMS`),
    squared norms, the unit atoms and the CSR neighbour lists of the unit atoms
    (empty when M^2 N > :data:`_NEIGHBOUR_WORK`)."""
    from . import _search_kernel as sk

    def make(a: np.ndarray) -> tuple[np.ndarray, ...]:
        gnorm2 = np.einsum("mn,mn->m", a, a)
        unit = _frozen_view(a / np.sqrt(np.maximum(gnorm2, 1e-300))[:, None])
        if a.shape[0] ** 2 * a.shape[1] <= _NEIGHBOUR_WORK:
            indptr, indices = sk.neighbours(unit)
        else:
            indptr, indices = np.zeros(0, np.int64), np.zeros(0, np.int64)
        gram = a @ a.T if a.shape[0] <= _GRAM_ATOMS else np.zeros((0, 0))
        return (_frozen_view(a), _frozen_view(gram), _frozen_view(gnorm2), unit,
                _frozen_view(indptr, np.int64), _frozen_view(indices, np.int64))

    return _memo(g, make, readonly=not g.flags.writeable)


def _plan_views(plan: TuplePlan) -> tuple[np.ndarray, ...]:
    """Read-only kernel arguments of a (cached, immutable) tuple plan."""
    return _memo(plan, lambda p: (
        _frozen_view(p.atoms), _frozen_view(p.subset, np.int64),
        _frozen_view(p.columns, np.uint64), _frozen_view(p.prefixes, np.uint64),
        _frozen_view(p.prefix_inv, p.ext.dtype), _frozen_view(p.ext_ptr, np.int64),
        _frozen_view(p.ext, p.ext.dtype),
        _frozen_view(p.near, np.bool_)))


def grid_search(
    g: np.ndarray, data: np.ndarray, k: int, max_sweeps: int = 8, n_coarse: int = 3,
    budget: int = TUPLE_BUDGET, n_alt: int = 2, distinct: bool = False, pursuit: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate K-atom explanations of every data vector (compiled, one trial at a time).

    Same stages, scores and tie-breaking as :func:`grid_search_numpy` (see there for
    the parameters and returns), run by :mod:`olsbayes.ml._search_kernel`; the
    scores differ from the numpy ones by rounding only.
    """
    from . import _search_kernel as sk  # numba is imported on first use
    from . import _tuple_kernel as tk

    gv, gram, gnorm2, unit, indptr, indices = _atom_views(g)
    plans = tuple_plans(g, k, n_coarse, budget) if k >= 2 else []
    pursuit = pursuit or not plans
    t, first, n_p = data.shape[0], (1 + k * n_alt) * pursuit, len(plans)
    idx = np.empty((t, first + n_p * (1 + bool(distinct)), k), dtype=np.int64)
    s = _frozen_view(data)
    if pursuit:
        sk.search_trials(gv, gram, gnorm2, unit, indptr, indices, s, k, max_sweeps, n_alt, idx)
    for j, plan in enumerate(plans):
        tk.tuple_trials(*_plan_views(plan), s, idx, first + j,
                        first + n_p + j if distinct else -1)
    inten, rss = np.empty(idx.shape), np.empty(idx.shape[:2])
    sk.intensities_trials(gv, s, idx, inten, rss)
    return idx, inten, rss


def grid_search_numpy(
    g: np.ndarray, data: np.ndarray, k: int, max_sweeps: int = 8, n_coarse: int = 3,
    budget: int = TUPLE_BUDGET, n_alt: int = 2, distinct: bool = False, pursuit: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate K-atom explanations of every data vector (numpy reference).

    Parameters
    ----------
    g : ndarray, shape (M, N)
        Atom responses (unit intensity).
    data : ndarray, shape (T, N)
    k : int
        Number of sources.
    max_sweeps : int
        Maximum alternating-projection sweeps.
    n_coarse : int
        For K >= 2, number of differently placed coarse atom subsets whose best
        K-tuple (:mod:`olsbayes.ml.tuples`) is one more candidate (subsets that
        coincide, or have no full-rank K-tuple, count once or not at all:
        ``n_p <= n_coarse`` plans, :func:`~olsbayes.ml.tuples.tuple_plans`).
    budget : int
        Cap on the number of K-tuples per coarse subset (sets its size).
    n_alt : int
        Runner-up positions per source (given the others) added as candidates.
    distinct : bool
        Also each coarse subset's best tuple outside the basins of its best one
        (:func:`~olsbayes.ml.tuples.tuple_search`): a second mode, e.g. the
        rotated alias of a near-equilateral K = 3 scene.
    pursuit : bool
        Run the pursuit, alternation and runners-up (the first 1 + K n_alt
        candidates).  False: the coarse subsets' tuples only (where there is at
        least one plan; else the pursuit runs anyway).

    Returns
    -------
    idx : ndarray of int, shape (T, C, K)
        C = (1 + K n_alt if pursuit else 0) + (n_p (2 if distinct else 1) if K >= 2
        else 0) candidate atom sets per trial: pursuit + alternation, the runners-up,
        the best tuples of the subsets, then their second modes.
    intensity : ndarray, shape (T, C, K)
        Their least-squares intensities, clipped at 0.
    rss : ndarray, shape (T, C)
        Their (unconstrained) least-squares residual sums of squares.
    """
    gnorm2 = np.einsum("mn,mn->m", g, g)
    plans = tuple_plans(g, k, n_coarse, budget) if k >= 2 else []
    parts = [
        _search_chunk(g, gnorm2, data[i : i + _CHUNK], k, max_sweeps, plans, n_alt, distinct,
                      pursuit or not plans)
        for i in range(0, data.shape[0], _CHUNK)
    ]
    idx = np.concatenate(parts, axis=0)
    return (idx, *_intensities(g, data, idx))
