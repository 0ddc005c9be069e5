"""Exhaustive search over K-tuples of a coarse atom grid (for K >= 2 sources).

Greedy pursuit and alternating projection can stall in a wrong configuration
when every source is seen by half of the sub-sensors (the clipped cosine) and
three or more sources overlap.  Enumerating every K-tuple of a *coarse* atom
set, with intensities solved linearly (least squares, tuples with a negative
intensity dropped), finds the right basin; the fine alternating projection and
the LM refinement then polish it.  The M_c coarse atoms are chosen so that the
number of tuples stays within a budget.

Each tuple is solved by extending its *prefix* (its first K - 1 atoms, in
lexicographic order all tuples of a prefix are consecutive): with the prefix's
solution ``f = A_p^-1 b_p`` and score ``b_p . f`` computed once per prefix, and
per tuple the precomputed regression ``w = A_p^-1 g_p,d`` of its last atom d
on the prefix atoms and ``1 / schur``, ``schur = g_dd - g_p,d . w``::

    r = b_d - w . b_p,   I_d = r / schur,   I_p = f - w I_d,
    score = b_p . f + r I_d            (the drop in the residual sum of squares)

-- block elimination of the tuple's normal equations: 2 K multiply-adds per tuple
(K - 1 for r, 2 for I_d and the score, K - 1 for the signs of I_p) instead of
K (K + 1) with its K x K inverse.  Cost O(C(M_c, K) K) per data vector.  The
scan itself is compiled (:mod:`olsbayes.ml._numba.tuples`); this module plans it, on
the coarse subsets of :mod:`~olsbayes.ml.fast.coarse`.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from math import comb

import numpy as np

from ..atoms import GRAM_ATOMS, NEIGHBOUR
from .coarse import GRAM_SAMPLING_ENTRIES, coarse_size, coarse_subsets

__all__ = ["tuple_plans", "TuplePlan"]


@dataclass(frozen=True)
class TuplePlan:
    """Precomputed tuple search on one coarse subset (internal).

    Tuples (rows of ``combos``, lexicographic) are grouped by their prefix (first
    K - 1 atoms): those of prefix r are ``combos[ext_ptr[r]:ext_ptr[r + 1]]``.
    """

    subset: np.ndarray  # (Mc,) indices of the coarse atoms in the fine grid
    atoms: np.ndarray  # (Mc, N)
    combos: np.ndarray  # (C, K) tuples of coarse indices with a regular Gram matrix
    columns: np.ndarray  # (K, C) combos.T, C-contiguous (gathers read it row by row)
    prefixes: np.ndarray  # (K - 1, R) coarse indices of the distinct prefixes
    prefix_inv: np.ndarray  # (K - 1, K - 1, R) inverse Gram matrix of each prefix
    ext_ptr: np.ndarray  # (R + 1,) tuple ranges of the prefixes
    ext: np.ndarray  # (K + 1, C) per tuple: w (K - 1 rows), 1 / schur and its number
    near: np.ndarray  # (Mc, Mc) bool: coarse atoms in one basin (correlation > NEIGHBOUR)


#: Gram matrices with det > SURE_REGULAR * trace^K pass :func:`_regular` without
#: their eigenvalues, far inside the 1e-10 condition bound (see :func:`_regular`).
SURE_REGULAR = 1e-8


def _det(a: np.ndarray) -> np.ndarray:
    """Determinants of a (C, K, K), K = 2, 3 or 4, vectorised over C.

    K = 3 by cofactors of the first row; K = 4 by Laplace's expansion in the 2 x 2
    minors of the first two rows and of the last two.
    """
    k = a.shape[-1]
    if k == 2:
        return a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    if k == 3:
        return (a[:, 0, 0] * (a[:, 1, 1] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 1])
                - a[:, 0, 1] * (a[:, 1, 0] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 0])
                + a[:, 0, 2] * (a[:, 1, 0] * a[:, 2, 1] - a[:, 1, 1] * a[:, 2, 0]))

    def minor(r: int, i: int, j: int) -> np.ndarray:  # rows r, r + 1; columns i, j
        return a[:, r, i] * a[:, r + 1, j] - a[:, r, j] * a[:, r + 1, i]

    return (minor(0, 0, 1) * minor(2, 2, 3) - minor(0, 0, 2) * minor(2, 1, 3)
            + minor(0, 0, 3) * minor(2, 1, 2) + minor(0, 1, 2) * minor(2, 0, 3)
            - minor(0, 1, 3) * minor(2, 0, 2) + minor(0, 2, 3) * minor(2, 0, 1))


def _regular(a: np.ndarray) -> np.ndarray:
    """Tuples whose Gram matrix a (C, K, K) is regular: ``w_min > 1e-10 w_max`` (eigvalsh).

    For a positive semi-definite matrix ``w_max <= trace`` and ``det <= w_min
    w_max^(K-1)``, so ``det > SURE_REGULAR trace^K`` proves ``w_min > 1e-8 w_max``;
    the determinant's rounding (a few times ``K! eps trace^K``) and LAPACK's
    eigenvalues' (``eps w_max``) are far below that margin, so eigvalsh would keep
    such a tuple too.  Only the others (near-collinear atoms) go to
    eigvalsh: the same tuples, without one LAPACK call per tuple (about 2 us each;
    24 plans of 4845 tuples at K = 4 took 0.23 s).  K > 4: eigvalsh for all.
    """
    k = a.shape[-1]
    sure = np.zeros(a.shape[0], dtype=bool)
    if 2 <= k <= 4:
        sure = _det(a) > SURE_REGULAR * np.trace(a, axis1=1, axis2=2) ** k
    keep = sure.copy()
    rest = np.flatnonzero(~sure)
    if rest.size:
        w = np.linalg.eigvalsh(a[rest])
        keep[rest] = w[:, 0] > 1e-10 * w[:, -1]
    return keep


@functools.lru_cache(maxsize=32)
def _combinations(n: int, k: int) -> np.ndarray:
    """Every K-subset of range(n) in lexicographic order, (C(n, K), K), read-only.

    Memoised: the plans of one fit share n and K (24 of them at K = 4, where
    building the array from Python tuples took about 4 ms a plan).
    """
    flat = itertools.chain.from_iterable(itertools.combinations(range(n), k))
    out = np.fromiter(flat, dtype=np.int64, count=comb(n, k) * k).reshape(-1, k)
    out.flags.writeable = False
    return out


def _plan(g: np.ndarray, subset: np.ndarray, k: int, dtype: type) -> TuplePlan:
    gc = g[subset]
    combos = _combinations(gc.shape[0], k)
    gram = gc @ gc.T
    a = gram[combos[:, :, None], combos[:, None, :]]  # (C, K, K)
    combos = combos[_regular(a)]  # (a prefix of a regular tuple is regular)
    new = np.ones(combos.shape[0], bool)
    new[1:] = np.any(combos[1:, :-1] != combos[:-1, :-1], axis=1)
    start = np.flatnonzero(new)
    pre = combos[start, :-1]  # (R, K - 1)
    pre_inv = np.linalg.inv(gram[pre[:, :, None], pre[:, None, :]])  # (R, K-1, K-1)
    owner = np.cumsum(new) - 1  # prefix of each tuple
    last = combos[:, -1]
    cross = gram[pre[owner], last[:, None]]  # (C, K - 1)
    reg = np.einsum("cij,cj->ci", pre_inv[owner], cross)
    schur = gram[last, last] - np.einsum("ci,ci->c", cross, reg)
    unit = gc / np.sqrt(np.maximum(np.diag(gram), 1e-300))[:, None]
    ext = np.column_stack([reg, 1.0 / schur, np.arange(combos.shape[0])]).T
    if combos.shape[0] > 2**24:  # tuple numbers beyond float32's integers
        dtype = np.float64
    return TuplePlan(
        subset, gc, combos, np.ascontiguousarray(combos.T), np.ascontiguousarray(pre.T),
        np.ascontiguousarray(np.moveaxis(pre_inv, 0, -1), dtype=dtype),
        np.append(start, combos.shape[0]).astype(np.int64),
        np.ascontiguousarray(ext, dtype=dtype), unit @ unit.T > NEIGHBOUR)


_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 16
_DIGESTS: dict = {}  # id -> (weakref, digest) of read-only atom arrays


def _digest(g: np.ndarray) -> str:
    """SHA-1 of the atoms; memoised for read-only arrays (the cached atoms of a model)."""
    hit = _DIGESTS.get(id(g))
    if hit is not None and hit[0]() is g and not g.flags.writeable:
        return hit[1]
    digest = hashlib.sha1(np.ascontiguousarray(g).view(np.uint8)).hexdigest()
    if not g.flags.writeable:
        if len(_DIGESTS) >= _CACHE_SIZE:
            _DIGESTS.clear()
        _DIGESTS[id(g)] = (weakref.ref(g), digest)
    return digest


def tuple_plans(g: np.ndarray, k: int, n_sets: int, budget: int, dtype: type,
                gram: np.ndarray | None = None) -> list:
    """Tuple-search plans for ``n_sets`` coarse subsets of the atoms g (cached).

    ``dtype``: the float type the tuples are scored in (float64 anyway where the
    tuple numbers exceed float32's integers).

    The subsets are distinct (:func:`~olsbayes.ml.fast.coarse.coarse_subsets`): a
    repeated subset would only repeat its best tuple and that tuple's LM run.

    The plans depend only on the atoms, K, ``n_sets`` and ``budget``, so repeated
    single fits with one model reuse them (an LRU cache of 16 entries keyed by a
    hash of the atoms, computed once per read-only atom array).  Atom matrices of
    more than :data:`~olsbayes.ml.fast.coarse.GRAM_SAMPLING_ENTRIES` entries and at
    most :data:`~olsbayes.ml.atoms.GRAM_ATOMS` atoms pick their
    subsets on their Gram matrix (``gram``, (M, M), computed here if not given).
    """
    size = coarse_size(g.shape[0], g.shape[1], k, budget)
    if size == 0 or n_sets == 0:
        return []
    dtype = np.dtype(dtype)
    key = (_digest(g), g.shape, k, n_sets, size, dtype.str)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    if g.size > GRAM_SAMPLING_ENTRIES and g.shape[0] <= GRAM_ATOMS:
        gram = g @ g.T if gram is None or gram.shape[0] != g.shape[0] else gram
    else:
        gram = None
    plans = [_plan(g, sub, k, dtype) for sub in coarse_subsets(g, size, n_sets, gram)]
    plans = [p for p in plans if p.combos.shape[0]]  # no K-tuple of full rank
    _CACHE[key] = plans
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return plans
