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

from ...geometry import lonlat_to_unit
from ...model import Model
from ...sensitivity import is_clipped_cosine
from ..atoms import GRAM_ATOMS, NEIGHBOUR, gram_from_arcs
from .options import FastOptions
from .tuples import TuplePlan, tuple_plans

__all__ = ["arc_views", "grid_search", "model_views", "tree_views"]


def _frozen_view(a: np.ndarray, dtype: type = float) -> np.ndarray:
    """A C-contiguous read-only view (one array type, so one compiled signature)."""
    v = np.ascontiguousarray(a, dtype=dtype).view()
    v.flags.writeable = False
    return v


_VIEWS: dict = {}  # id -> (weakref, views) of read-only atom arrays and tuple plans


def _memo(obj: object, make, readonly: bool = True, cache: dict | None = None) -> tuple:
    """``make(obj)``, memoised for a live read-only object (the cached atoms, plans).

    ``cache``: the dict of one kind of derived arrays (default: the kernel views).
    """
    cache = _VIEWS if cache is None else cache
    hit = cache.get(id(obj))
    if hit is not None and hit[0]() is obj:
        return hit[1]
    out = make(obj)
    if readonly:
        if len(cache) >= 64:
            cache.clear()
        cache[id(obj)] = (weakref.ref(obj), out)
    return out


#: Largest M^2 N for which the atoms' basins (neighbour lists) come from the unit
#: atoms' dot products; larger atom sets take them from the Gram matrix when it exists.
_NEIGHBOUR_WORK = 50_000_000


def _gram_neighbours(gram: np.ndarray, gnorm2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR lists of the atoms within each atom's basin, from the Gram matrix, O(M^2).

    The normalised correlations ``gram[a, b] / sqrt(gnorm2[a] gnorm2[b])`` against
    :data:`~olsbayes.ml.atoms.NEIGHBOUR` (the unit atoms' dot products up to rounding).
    """
    inv = 1.0 / np.sqrt(np.maximum(gnorm2, 1e-300))
    near = gram * inv[:, None] * inv[None, :] > NEIGHBOUR
    indptr = np.concatenate([[0], np.cumsum(near.sum(axis=1))]).astype(np.int64)
    return indptr, np.nonzero(near)[1].astype(np.int64)


_ARC_ATOMS: dict = {}  # id -> (weakref, views) of ring atoms whose Gram came from their arcs


def _atom_views(g: np.ndarray, arcs: tuple | None = None) -> tuple[np.ndarray, ...]:
    """Read-only views of the atoms and of the arrays derived from them.

    The atoms; their Gram matrix (empty when M > :data:`~olsbayes.ml.atoms.GRAM_ATOMS`;
    from ``arcs``, the ring atoms' arcs of :func:`arc_views`, beyond
    :data:`~olsbayes.ml.atoms.ARC_GRAM_SENSORS` sub-sensors); squared norms; the unit
    atoms; and the CSR neighbour lists of the unit atoms: from their dot products when
    M^2 N <= :data:`_NEIGHBOUR_WORK`, else from the Gram matrix
    (:func:`_gram_neighbours`), else empty (the searches then scan every atom).  The
    unit atoms are read only by those two scans; where neither runs they are an
    (M, 0) placeholder.  Views made with arcs are memoised apart from those without.
    """
    from .._numba import search as sk

    m, n = g.shape
    by_arcs = gram_from_arcs(arcs is not None and arcs[3].size > 0, n)

    def make(a: np.ndarray) -> tuple[np.ndarray, ...]:
        gnorm2 = np.einsum("mn,mn->m", a, a)
        gram = np.zeros((0, 0))
        if m <= GRAM_ATOMS and by_arcs:
            gram = np.empty((m, m))
            sk.arc_gram(arcs, gram)
        elif m <= GRAM_ATOMS:
            gram = a @ a.T
        scan = m * m * n <= _NEIGHBOUR_WORK
        unit = np.zeros((m, 0))
        if scan or not gram.size:
            unit = a / np.sqrt(np.maximum(gnorm2, 1e-300))[:, None]
        unit = _frozen_view(unit)
        if scan:
            indptr, indices = sk.neighbours(unit)
        elif gram.size:
            indptr, indices = _gram_neighbours(gram, gnorm2)
        else:
            indptr, indices = np.zeros(0, np.int64), np.zeros(0, np.int64)
        return (_frozen_view(a), _frozen_view(gram), _frozen_view(gnorm2), unit,
                _frozen_view(indptr, np.int64), _frozen_view(indices, np.int64))

    return _memo(g, make, readonly=not g.flags.writeable,
                 cache=_ARC_ATOMS if by_arcs else None)


def _law_tol(g: np.ndarray) -> float:
    """Tolerance of the check that atoms g are the clipped cosine: 1e-12 of the largest entry."""
    return 1e-12 * max(float(g.max()), -float(g.min()), 1e-300)


_ARCS: dict = {}  # id -> (weakref, arcs) of read-only ring atom arrays
_PLAN_ARCS: dict = {}  # id -> (weakref, arcs) of tuple plans


def _ring_arcs(g: np.ndarray, normals: np.ndarray, angles: np.ndarray) -> tuple | None:
    """The sub-sensors each ring atom lights, as one arc of them in angular order.

    ``g`` (M, N) must be the clipped cosine of the directions ``angles`` (M,) or (M, 1)
    against ``normals`` (N, 2) (checked to 1e-12 of the largest entry, once:
    :func:`olsbayes.ml._numba.search.ring_arcs`), so that an atom's correlation with
    readings is ``cos a sum(s nx) + sin a sum(s ny)`` over the sub-sensors it lights,
    which on a ring are a run of them in angular order:
    :func:`olsbayes.ml._numba.search._arc_correlations` then costs O(M + N) instead
    of O(M N).  None (correlate with the atoms) when ``g`` is anything else.
    """
    from .._numba import search as sk

    angles = angles.ravel()
    if g.size == 0 or angles.size != g.shape[0]:
        return None
    ct, st = np.cos(angles), np.sin(angles)
    order = np.argsort(np.arctan2(normals[:, 1], normals[:, 0]), kind="stable")
    nx, ny = np.ascontiguousarray(normals[order, 0]), np.ascontiguousarray(normals[order, 1])
    lo, cnt = np.zeros(g.shape[0], np.int64), np.zeros(g.shape[0], np.int64)
    tol = _law_tol(g)
    if not sk.ring_arcs(_frozen_view(g), _frozen_view(order, np.int64), nx, ny, ct, st, tol,
                        lo, cnt):
        return None
    return (_frozen_view(order, np.int64), _frozen_view(nx), _frozen_view(ny),
            _frozen_view(lo, np.int64), _frozen_view(cnt, np.int64), _frozen_view(ct),
            _frozen_view(st))


_DENSE = tuple(_frozen_view(np.zeros(0), t) for t in (np.int64, float, float, np.int64,
                                                       np.int64, float, float))


def _views(g: np.ndarray, normals: np.ndarray | None, locs: np.ndarray | None, build,
           empty: tuple, cache: dict) -> tuple:
    """``build(g, normals, locs)`` (``empty`` where it gives None), memoised per read-only g.

    ``empty`` at once where ``normals`` or ``locs`` is None (not asked for).
    """
    if normals is None or locs is None:
        return empty

    def make(a: np.ndarray) -> tuple:
        out = build(a, np.asarray(normals, float), np.asarray(locs, float))
        return empty if out is None else out

    return _memo(g, make, readonly=not g.flags.writeable, cache=cache)


def arc_views(g: np.ndarray, normals: np.ndarray | None, angles: np.ndarray | None) -> tuple:
    """Kernel arguments of :func:`_ring_arcs` for ring atoms, memoised per read-only ``g``.

    Empty arrays where it does not apply (``normals`` None: not a ring; or atoms
    that are not the clipped cosine of ``angles``).
    """
    return _views(g, normals, angles, _ring_arcs, _DENSE, _ARCS)


_TREES: dict = {}  # id -> (weakref, tree) of read-only sphere atom arrays
#: A sphere atoms' tree is kept while its differences hold at most this share of the M N
#: atom entries: an entry (a gather and three multiply-adds) costs about eight atom
#: entries of ``G @ s`` (one vectorised multiply-add each).
_TREE_SHARE = 0.125
#: Largest M for which a tree is built: Prim's algorithm costs O(M^2) once per grid
#: (0.1 s at this M), and every default sphere grid is far below it.
_TREE_ATOMS = 8192
_NO_TREE = (*(_frozen_view(np.zeros(0), np.int64) for _ in range(4)),
            *(_frozen_view(np.zeros((0, 3))) for _ in range(2)))


def _sphere_tree(g: np.ndarray, normals: np.ndarray, lonlat: np.ndarray) -> tuple | None:
    """Sphere atoms' correlations over a spanning tree (:mod:`olsbayes.ml._numba.hemispheres`).

    ``g`` (M, N) must be the clipped cosine of the directions ``lonlat`` (M, 2)
    against ``normals`` (N, 3) (checked to 1e-12 of the largest entry, once), so
    that the atoms' correlations with readings follow one from another over the
    tree in O(M + L) instead of O(M N).  None (correlate with the atoms) when
    ``g`` is anything else, has more than :data:`_TREE_ATOMS` atoms, or the tree
    would not save work.
    """
    m, n = g.shape
    if g.size == 0 or m > _TREE_ATOMS or lonlat.shape != (m, 2) or normals.shape != (n, 3):
        return None
    from .._numba import hemispheres as hs

    u = _frozen_view(lonlat_to_unit(lonlat[:, 0], lonlat[:, 1]))
    tol = _law_tol(g)
    ok, *tree = hs.hemisphere_tree(_frozen_view(g), u, _frozen_view(normals), tol,
                                   int(_TREE_SHARE * g.size))
    return tuple(_frozen_view(a, a.dtype) for a in tree) + (u,) if ok else None


def tree_views(g: np.ndarray, normals: np.ndarray | None, lonlat: np.ndarray | None) -> tuple:
    """Kernel arguments of :func:`_sphere_tree` for sphere atoms, memoised per read-only ``g``.

    Empty arrays where it does not apply (``normals`` None: not a sphere; or atoms
    that are not the clipped cosine of ``lonlat``).
    """
    return _views(g, normals, lonlat, _sphere_tree, _NO_TREE, _TREES)


def model_views(model: Model, g: np.ndarray, grid: np.ndarray) -> tuple[tuple, tuple]:
    """The ring arcs and sphere tree of a model's atoms g (M, N) on ``grid`` (M, d).

    :func:`arc_views` for a ring with the clipped cosine, :func:`tree_views` for a
    sphere with it; the empty views of the other.
    """
    law = is_clipped_cosine(model.sensitivity)
    ring, sphere = law and model.kind == "angle", law and model.kind == "lonlat"
    normals = model.array.normals
    return (arc_views(g, normals if ring else None, grid if ring else None),
            tree_views(g, normals if sphere else None, grid if sphere else None))


def _plan_arcs(plan: TuplePlan, arcs: tuple) -> tuple:
    """The arcs of a plan's coarse atoms (those of its subset), memoised per plan.

    A plan belongs to the atoms it was built from, so its arcs are theirs.
    """
    if not arcs[3].size:
        return _DENSE
    return _memo(plan, lambda p: arcs[:3] + tuple(_frozen_view(a[p.subset], a.dtype)
                                                  for a in arcs[3:]), cache=_PLAN_ARCS)


def _plan_views(plan: TuplePlan) -> tuple[np.ndarray, ...]:
    """Read-only kernel arguments of a (cached, immutable) tuple plan."""
    return _memo(plan, lambda p: (
        _frozen_view(p.atoms), _frozen_view(p.subset, np.int64),
        _frozen_view(p.columns, np.uint64), _frozen_view(p.prefixes, np.uint64),
        _frozen_view(p.prefix_inv, p.ext.dtype), _frozen_view(p.ext_ptr, np.int64),
        _frozen_view(p.ext, p.ext.dtype),
        _frozen_view(p.near, np.bool_)))


def grid_search(g: np.ndarray, data: np.ndarray, k: int, options: FastOptions,
                arcs: tuple = _DENSE, tree: tuple = _NO_TREE
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate K-atom explanations of every data vector (compiled, one trial at a time).

    Parameters
    ----------
    g : ndarray, shape (M, N)
        Atom responses (unit intensity), read-only for the memoised kernel views.
    data : ndarray, shape (T, N)
    k : int
        Number of sources.
    options : FastOptions
        Resolved for K (:meth:`FastOptions.resolve`): ``max_sweeps``, ``n_coarse``
        differently placed coarse subsets whose best K-tuple
        (:mod:`~olsbayes.ml.fast.tuples`) is one more candidate each (subsets that
        coincide, or have no full-rank K-tuple, count once or not at all: ``n_p <=
        n_coarse`` plans), ``tuple_budget`` (K-tuples per subset),
        ``single_precision``, ``runners_up`` (positions per source given the
        others), ``distinct_modes`` (each subset's best tuple outside the basins of
        its best one too: a second mode) and ``pursuit`` (pursuit, alternation and
        runners-up as the first 1 + K runners_up candidates; where no coarse plan
        exists the pursuit runs anyway).
    arcs : tuple, optional
        Ring atoms as arcs of lit sub-sensors (:func:`arc_views`): the pursuit's
        correlations in O(M + N) per data vector instead of O(M N).
    tree : tuple, optional
        Sphere atoms over their spanning tree (:func:`tree_views`): the pursuit's
        correlations in O(M + L) per data vector instead of O(M N).  (The coarse
        subsets' atoms lie too far apart for a tree of their own to save work.)

    Returns
    -------
    idx : ndarray of int, shape (T, C, K)
        Candidate atom sets per trial: pursuit + alternation, the runners-up, the
        best tuples of the subsets, then their second modes.
    intensity : ndarray, shape (T, C, K)
        Their least-squares intensities, clipped at 0.
    rss : ndarray, shape (T, C)
        Their (unconstrained) least-squares residual sums of squares.
    """
    from .._numba import search as sk  # numba is imported on first use
    from .._numba import tuples as tk

    gv, gram, gnorm2, unit, indptr, indices = _atom_views(g, arcs)
    dtype = np.float32 if options.single_precision else np.float64
    plans = (tuple_plans(g, k, options.n_coarse, options.tuple_budget, dtype, gram)
             if k >= 2 else [])
    pursuit = options.pursuit or not plans
    n_alt, distinct = options.runners_up, options.distinct_modes
    t, first, n_p = data.shape[0], (1 + k * n_alt) * pursuit, len(plans)
    idx = np.empty((t, first + n_p * (1 + bool(distinct)), k), dtype=np.int64)
    s = _frozen_view(data)
    if pursuit:
        sk.search_trials(gv, gram, gnorm2, unit, indptr, indices, arcs, tree, s, k,
                         options.max_sweeps, n_alt, idx)
    for j, plan in enumerate(plans):
        tk.tuple_trials(*_plan_views(plan), _plan_arcs(plan, arcs), s, idx, first + j,
                        first + n_p + j if distinct else -1)
    inten, rss = np.empty(idx.shape), np.empty(idx.shape[:2])
    sk.intensities_trials(gv, s, idx, inten, rss)
    return idx, inten, rss
