"""Compiled (numba) exhaustive K-tuple search (:func:`olsbayes.ml.tuples.tuple_search`).

For each trial and coarse subset: the feasible K-tuple (all least-squares
intensities >= 0) with the largest drop in the residual sum of squares, and
optionally (``distinct``) the best tuple none of whose atoms lies in the basin
(normalised correlation > NEIGHBOUR) of an atom of the first -- a second mode of
the likelihood, e.g. the rotated alias of a near-equilateral K = 3 scene.  Same
arithmetic and tie-breaking (first maximum, in tuple order) as the numpy
reference, so the same tuples.
"""

from __future__ import annotations

import numba
import numpy as np

from ._search_kernel import _matvec

__all__ = ["TUPLE_BLOCK", "tuple_trials"]

#: Trials per block of the tuple search: each tuple's inverse Gram matrix is read
#: once per block and applied to every trial of it (unit-stride over trials).
TUPLE_BLOCK = 64


@numba.njit(cache=True)
def _tuple_scores(corr, columns, inv_rows, out):  # pragma: no cover - compiled
    """out[c]: RSS drop of K-tuple c, -inf if infeasible (some coefficient < 0).

    coef_a = sum_b A^-1_ab corr_b and score = sum_a corr_a coef_a, summed in the
    order of tuples.tuple_search.  No loop-carried dependence, so the loop
    vectorises (the running maximum is a separate pass).  K = 2 and 3 unrolled;
    ``columns`` unsigned (no negative-index wraparound per gather).
    """
    k, n_c = columns.shape
    if k == 2:
        for c in range(n_c):
            b0, b1 = corr[columns[0, c]], corr[columns[1, c]]
            f0 = inv_rows[0, 0, c] * b0 + inv_rows[0, 1, c] * b1
            f1 = inv_rows[1, 0, c] * b0 + inv_rows[1, 1, c] * b1
            sc = b0 * f0 + b1 * f1
            out[c] = sc if (f0 >= 0.0) & (f1 >= 0.0) else -np.inf
        return
    if k == 3:
        for c in range(n_c):
            b0, b1, b2 = corr[columns[0, c]], corr[columns[1, c]], corr[columns[2, c]]
            f0 = inv_rows[0, 0, c] * b0 + inv_rows[0, 1, c] * b1 + inv_rows[0, 2, c] * b2
            f1 = inv_rows[1, 0, c] * b0 + inv_rows[1, 1, c] * b1 + inv_rows[1, 2, c] * b2
            f2 = inv_rows[2, 0, c] * b0 + inv_rows[2, 1, c] * b1 + inv_rows[2, 2, c] * b2
            sc = b0 * f0 + b1 * f1 + b2 * f2
            out[c] = sc if (f0 >= 0.0) & (f1 >= 0.0) & (f2 >= 0.0) else -np.inf
        return
    for c in range(n_c):
        sc, feasible = 0.0, True
        for a in range(k):
            cf = inv_rows[a, 0, c] * corr[columns[0, c]]
            for b in range(1, k):
                cf += inv_rows[a, b, c] * corr[columns[b, c]]
            feasible = feasible and cf >= 0.0
            sc += corr[columns[a, c]] * cf
        out[c] = sc if feasible else -np.inf


@numba.njit(cache=True)
def _first_max(scores, columns, blocked, masked):  # pragma: no cover - compiled
    """(index, value) of the first maximum of scores (0, -inf if all are -inf);
    ``masked``: tuples with a ``blocked`` atom are skipped."""
    best, arg = -np.inf, 0
    for c in range(scores.size):
        if scores[c] > best:
            if masked:
                hit = False
                for a in range(columns.shape[0]):
                    hit = hit or blocked[columns[a, c]]
                if hit:
                    continue
            best, arg = scores[c], c
    return arg, best


@numba.njit(cache=True)
def _block_best(corr_t, columns, inv_rows, blocked_t, masked, best, arg):  # pragma: no cover
    """:func:`_tuple_scores` and :func:`_first_max` for a block of trials at once, K = 2..4.

    corr_t (Mc, B): coarse correlations, one column per trial; blocked_t (Mc, B)
    the blocked atoms per trial (used if ``masked``); best (B,) and arg (B,) are
    reset (-inf, 0) and set in tuple order (strictly greater: the first maximum), with
    the same arithmetic per trial as :func:`_tuple_scores`, so the same tuples.
    """
    k, n_c = columns.shape
    nb = best.size
    best[:] = -np.inf
    arg[:] = 0
    for c in range(n_c):
        i0, i1 = columns[0, c], columns[1, c]
        if k == 2:
            a00, a01 = inv_rows[0, 0, c], inv_rows[0, 1, c]
            a10, a11 = inv_rows[1, 0, c], inv_rows[1, 1, c]
            for tb in range(nb):
                b0, b1 = corr_t[i0, tb], corr_t[i1, tb]
                f0 = a00 * b0 + a01 * b1
                f1 = a10 * b0 + a11 * b1
                sc = b0 * f0 + b1 * f1
                up = (f0 >= 0.0) & (f1 >= 0.0) & (sc > best[tb])
                if masked:
                    up = up & (not (blocked_t[i0, tb] | blocked_t[i1, tb]))
                best[tb] = sc if up else best[tb]
                arg[tb] = c if up else arg[tb]
        elif k == 3:
            i2 = columns[2, c]
            a00, a01, a02 = inv_rows[0, 0, c], inv_rows[0, 1, c], inv_rows[0, 2, c]
            a10, a11, a12 = inv_rows[1, 0, c], inv_rows[1, 1, c], inv_rows[1, 2, c]
            a20, a21, a22 = inv_rows[2, 0, c], inv_rows[2, 1, c], inv_rows[2, 2, c]
            for tb in range(nb):
                b0, b1, b2 = corr_t[i0, tb], corr_t[i1, tb], corr_t[i2, tb]
                f0 = a00 * b0 + a01 * b1 + a02 * b2
                f1 = a10 * b0 + a11 * b1 + a12 * b2
                f2 = a20 * b0 + a21 * b1 + a22 * b2
                sc = b0 * f0 + b1 * f1 + b2 * f2
                up = (f0 >= 0.0) & (f1 >= 0.0) & (f2 >= 0.0) & (sc > best[tb])
                if masked:
                    up = up & (not (blocked_t[i0, tb] | blocked_t[i1, tb] | blocked_t[i2, tb]))
                best[tb] = sc if up else best[tb]
                arg[tb] = c if up else arg[tb]
        else:
            i2, i3 = columns[2, c], columns[3, c]
            for tb in range(nb):
                b0, b1, b2, b3 = corr_t[i0, tb], corr_t[i1, tb], corr_t[i2, tb], corr_t[i3, tb]
                f0 = inv_rows[0, 0, c] * b0 + inv_rows[0, 1, c] * b1
                f0 = f0 + inv_rows[0, 2, c] * b2 + inv_rows[0, 3, c] * b3
                f1 = inv_rows[1, 0, c] * b0 + inv_rows[1, 1, c] * b1
                f1 = f1 + inv_rows[1, 2, c] * b2 + inv_rows[1, 3, c] * b3
                f2 = inv_rows[2, 0, c] * b0 + inv_rows[2, 1, c] * b1
                f2 = f2 + inv_rows[2, 2, c] * b2 + inv_rows[2, 3, c] * b3
                f3 = inv_rows[3, 0, c] * b0 + inv_rows[3, 1, c] * b1
                f3 = f3 + inv_rows[3, 2, c] * b2 + inv_rows[3, 3, c] * b3
                sc = b0 * f0 + b1 * f1 + b2 * f2 + b3 * f3
                up = (f0 >= 0.0) & (f1 >= 0.0) & (f2 >= 0.0) & (f3 >= 0.0) & (sc > best[tb])
                if masked:
                    up = up & (not (blocked_t[i0, tb] | blocked_t[i1, tb] | blocked_t[i2, tb]
                                    | blocked_t[i3, tb]))
                best[tb] = sc if up else best[tb]
                arg[tb] = c if up else arg[tb]


@numba.njit(cache=True)
def _block(near, columns, arg, out):  # pragma: no cover - compiled
    """out[u]: coarse atom u is in the basin of an atom of tuple ``arg``."""
    for u in range(out.size):
        hit = False
        for a in range(columns.shape[0]):
            hit = hit or near[columns[a, arg], u]
        out[u] = hit


@numba.njit(cache=True)
def _write(subset, columns, arg, out_row):  # pragma: no cover - compiled
    for a in range(columns.shape[0]):
        out_row[a] = subset[columns[a, arg]]


@numba.njit(cache=True)
def _per_trial(atoms, subset, columns, inv_rows, near, data, out, col, col2):  # pragma: no cover
    """:func:`tuple_trials` one trial at a time: all scores, then the first maxima."""
    mc = atoms.shape[0]
    corr, blocked = np.empty(mc), np.zeros(mc, np.bool_)
    scores = np.empty(columns.shape[1])
    for i in range(data.shape[0]):
        _matvec(atoms, data[i], corr)
        _tuple_scores(corr, columns, inv_rows, scores)
        arg, _ = _first_max(scores, columns, blocked, False)
        _write(subset, columns, arg, out[i, col])
        if col2 >= 0:  # the same scores, tuples with an atom in a basin of the best skipped
            _block(near, columns, arg, blocked)
            arg2, best2 = _first_max(scores, columns, blocked, True)
            _write(subset, columns, arg2 if best2 > -np.inf else arg, out[i, col2])


@numba.njit(cache=True)
def tuple_trials(atoms, subset, columns, inv_rows, near, data, out, col,
                 col2):  # pragma: no cover - compiled
    """Best feasible K-tuple of one coarse plan per trial into out[:, col], and with
    col2 >= 0 the best one outside its atoms' basins (``near`` (Mc, Mc)) into
    out[:, col2] (the first one again if there is none) (tuples.tuple_search).

    K = 2..4 in blocks of up to :data:`TUPLE_BLOCK` trials (:func:`_block_best`), other
    K (and K <= 3 for fewer than 4 trials) one trial at a time (:func:`_per_trial`);
    the same tuples either way.
    """
    k = columns.shape[0]
    mc, t = atoms.shape[0], data.shape[0]
    if k < 2 or k > 4 or (t < 4 and k < 4):  # (K <= 3: one lane is slower blocked)
        _per_trial(atoms, subset, columns, inv_rows, near, data, out, col, col2)
        return
    nb = min(TUPLE_BLOCK, t)  # a single fit scans one lane
    corr, corr_t = np.empty(mc), np.zeros((mc, nb))
    blocked, blocked_t = np.empty(mc, np.bool_), np.zeros((mc, nb), np.bool_)
    best, args = np.empty(nb), np.empty(nb, np.int64)
    best2, args2 = np.empty(nb), np.empty(nb, np.int64)
    for start in range(0, t, nb):
        m = min(nb, t - start)
        for tb in range(m):
            _matvec(atoms, data[start + tb], corr)
            for u in range(mc):
                corr_t[u, tb] = corr[u]
        _block_best(corr_t, columns, inv_rows, blocked_t, False, best, args)
        for tb in range(m):
            _write(subset, columns, args[tb], out[start + tb, col])
        if col2 < 0:
            continue
        for tb in range(m):  # (lanes >= m hold a previous block's trials: unused)
            _block(near, columns, args[tb], blocked)
            for u in range(mc):
                blocked_t[u, tb] = blocked[u]
        _block_best(corr_t, columns, inv_rows, blocked_t, True, best2, args2)
        for tb in range(m):
            arg = args2[tb] if best2[tb] > -np.inf else args[tb]
            _write(subset, columns, arg, out[start + tb, col2])
