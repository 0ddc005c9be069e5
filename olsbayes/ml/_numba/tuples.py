"""Compiled (numba) exhaustive K-tuple scan: twin of :mod:`olsbayes.ml.fast.tuples`.

For each trial and coarse subset: the feasible K-tuple (all least-squares
intensities >= 0) with the largest drop in the residual sum of squares, and
optionally (``distinct``) the best tuple none of whose atoms lies in the basin
(normalised correlation > NEIGHBOUR) of an atom of the first -- a second mode of
the likelihood, e.g. the rotated alias of a near-equilateral K = 3 scene.

Trials run in blocks of up to :data:`TUPLE_BLOCK` lanes, tuples grouped by their
prefix (:mod:`olsbayes.ml.fast.tuples`): each prefix's solution is computed once
per lane, each tuple extends it by block elimination.  Same arithmetic, in the
same order, as the numpy reference of the tests and the same tie-breaking (first
maximum, in tuple order), so the same tuples.

The lanes' running maxima are stored unconditionally (``max``) and their
arguments by a select, because a conditional store compiles to a masked vector
store that costs more than the rest of the loop.  K = 2, 3, 4 have kernels written
out per K (:func:`_block_best2` ...) that repeat the lanes' update on purpose: as a
called function, even inlined, it kept the loop from vectorising.

The kernels take the plan's float type (``FastOptions.single_precision``: K = 4
scores in float32, so a vector instruction holds twice the lanes), and the K = 4
first pass (no blocked atoms) skips the penalty matrix.  The constants -inf and 0
are taken from the lanes' arrays and a tuple's number from its plan (``ext``), so
that no float64 value enters a float32 loop.
"""

from __future__ import annotations

import numba
import numpy as np

from .search import _arc_correlations, _matvec

__all__ = ["PER_TRIAL_BELOW", "TUPLE_BLOCK", "tuple_trials"]

#: Trials per block of the tuple search: each tuple's coefficients are read once
#: per block and applied to every trial of it (unit-stride over trials).
TUPLE_BLOCK = 64
#: For K <= 3, fewer trials than this are searched one at a time (:func:`_per_trial`).
PER_TRIAL_BELOW = 4


@numba.njit(cache=True)
def _block_best_any(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best,
                    arg):  # pragma: no cover - compiled
    """:func:`_block_best` for any K, by loops over the prefix atoms."""
    km, nb, dt = prefixes.shape[0], best.size, best.dtype
    bp, f, sp = np.empty((km, nb), dt), np.empty((km, nb), dt), np.empty(nb, dt)
    best[:] = -np.inf
    arg[:] = 0.0
    neg, zero = best[0], arg[0]  # -inf and 0 as the scores' type
    for r in range(prefixes.shape[1]):
        for tb in range(nb):
            for i in range(km):
                bp[i, tb] = corr_t[prefixes[i, r], tb]
            for i in range(km):
                fi = prefix_inv[i, 0, r] * bp[0, tb]
                for j in range(1, km):
                    fi = fi + prefix_inv[i, j, r] * bp[j, tb]
                f[i, tb] = fi
            s = bp[0, tb] * f[0, tb]
            for i in range(1, km):
                s = s + bp[i, tb] * f[i, tb]
            for i in range(km):
                s = s + pen_t[prefixes[i, r], tb]
            sp[tb] = s
        for c in range(ext_ptr[r], ext_ptr[r + 1]):
            for tb in range(nb):
                acc = ext[0, c] * bp[0, tb]
                for i in range(1, km):
                    acc = acc + ext[i, c] * bp[i, tb]
                rr = corr_t[last[c], tb] - acc
                cd = rr * ext[km, c]
                sc = sp[tb] + rr * cd
                lo = cd
                for i in range(km):
                    lo = min(lo, f[i, tb] - ext[i, c] * cd)
                sc = sc + pen_t[last[c], tb] if lo >= zero else neg
                if sc > best[tb]:
                    best[tb], arg[tb] = sc, ext[km + 1, c]


@numba.njit(cache=True)
def _block_best(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, use_pen, best,
                arg):  # pragma: no cover - compiled
    """Best feasible tuple of every lane of a block.

    best (B,): its score (-inf: none); arg (B,): its number (0 if none); both of the
    plan's float type.  pen_t (Mc, B): 0, or with ``use_pen`` -inf for an atom
    blocked for the lane (the tuples holding it are skipped; adding 0 is exact);
    K = 4 without ``use_pen`` skips it.
    """
    km = prefixes.shape[0]
    if km == 1:
        _block_best2(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best, arg)
    elif km == 2:
        _block_best3(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best, arg)
    elif km == 3 and not use_pen:
        _block_best4(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, best, arg)
    else:
        _block_best_any(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best, arg)


@numba.njit(cache=True)
def _block_best2(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best,
                 arg):  # pragma: no cover - compiled
    """:func:`_block_best` for K = 2, unrolled (see :func:`_block_best4`)."""
    nb, dt = best.size, best.dtype
    b0, f0, sp = np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt)
    best[:] = -np.inf
    arg[:] = 0.0
    neg, zero = best[0], arg[0]
    for r in range(prefixes.shape[1]):
        i0, a00 = prefixes[0, r], prefix_inv[0, 0, r]
        for tb in range(nb):
            x0 = corr_t[i0, tb]
            g0 = a00 * x0
            b0[tb], f0[tb] = x0, g0
            sp[tb] = x0 * g0 + pen_t[i0, tb]
        for c in range(ext_ptr[r], ext_ptr[r + 1]):
            row, prow = corr_t[last[c]], pen_t[last[c]]
            w0, isc, fc = ext[0, c], ext[1, c], ext[2, c]
            for tb in range(nb):
                rr = row[tb] - w0 * b0[tb]
                cd = rr * isc
                sc = sp[tb] + rr * cd
                lo = min(cd, f0[tb] - w0 * cd)
                sc = sc + prow[tb] if lo >= zero else neg
                old = best[tb]
                arg[tb] = fc if sc > old else arg[tb]
                best[tb] = max(sc, old)


@numba.njit(cache=True)
def _block_best3(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, best,
                 arg):  # pragma: no cover - compiled
    """:func:`_block_best` for K = 3, unrolled (see :func:`_block_best4`)."""
    nb, dt = best.size, best.dtype
    b0, b1, f0, f1 = np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt)
    sp = np.empty(nb, dt)
    best[:] = -np.inf
    arg[:] = 0.0
    neg, zero = best[0], arg[0]
    for r in range(prefixes.shape[1]):
        i0, i1 = prefixes[0, r], prefixes[1, r]
        a00, a01 = prefix_inv[0, 0, r], prefix_inv[0, 1, r]
        a10, a11 = prefix_inv[1, 0, r], prefix_inv[1, 1, r]
        for tb in range(nb):
            x0, x1 = corr_t[i0, tb], corr_t[i1, tb]
            b0[tb], b1[tb] = x0, x1
            g0 = a00 * x0 + a01 * x1
            g1 = a10 * x0 + a11 * x1
            f0[tb], f1[tb] = g0, g1
            sp[tb] = x0 * g0 + x1 * g1 + pen_t[i0, tb] + pen_t[i1, tb]
        for c in range(ext_ptr[r], ext_ptr[r + 1]):
            row, prow = corr_t[last[c]], pen_t[last[c]]
            w0, w1, isc, fc = ext[0, c], ext[1, c], ext[2, c], ext[3, c]
            for tb in range(nb):
                rr = row[tb] - (w0 * b0[tb] + w1 * b1[tb])
                cd = rr * isc
                sc = sp[tb] + rr * cd
                lo = min(cd, min(f0[tb] - w0 * cd, f1[tb] - w1 * cd))
                sc = sc + prow[tb] if lo >= zero else neg
                old = best[tb]
                arg[tb] = fc if sc > old else arg[tb]
                best[tb] = max(sc, old)


@numba.njit(cache=True)
def _block_best4(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, best,
                 arg):  # pragma: no cover - compiled
    """:func:`_block_best` for K = 4 without blocked atoms, unrolled.

    The lanes' work arrays are allocated here, so the compiler knows they do not
    alias and vectorises over lanes.
    """
    nb, dt = best.size, best.dtype
    b0, b1, b2 = np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt)
    f0, f1, f2, sp = np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt), np.empty(nb, dt)
    best[:] = -np.inf
    arg[:] = 0.0
    neg, zero = best[0], arg[0]
    for r in range(prefixes.shape[1]):
        i0, i1, i2 = prefixes[0, r], prefixes[1, r], prefixes[2, r]
        a00, a01, a02 = prefix_inv[0, 0, r], prefix_inv[0, 1, r], prefix_inv[0, 2, r]
        a10, a11, a12 = prefix_inv[1, 0, r], prefix_inv[1, 1, r], prefix_inv[1, 2, r]
        a20, a21, a22 = prefix_inv[2, 0, r], prefix_inv[2, 1, r], prefix_inv[2, 2, r]
        for tb in range(nb):
            x0, x1, x2 = corr_t[i0, tb], corr_t[i1, tb], corr_t[i2, tb]
            b0[tb], b1[tb], b2[tb] = x0, x1, x2
            g0 = a00 * x0 + a01 * x1 + a02 * x2
            g1 = a10 * x0 + a11 * x1 + a12 * x2
            g2 = a20 * x0 + a21 * x1 + a22 * x2
            f0[tb], f1[tb], f2[tb] = g0, g1, g2
            sp[tb] = x0 * g0 + x1 * g1 + x2 * g2
        for c in range(ext_ptr[r], ext_ptr[r + 1]):
            row = corr_t[last[c]]
            w0, w1, w2, isc, fc = ext[0, c], ext[1, c], ext[2, c], ext[3, c], ext[4, c]
            for tb in range(nb):
                rr = row[tb] - (w0 * b0[tb] + w1 * b1[tb] + w2 * b2[tb])
                cd = rr * isc
                sc = sp[tb] + rr * cd
                lo = min(min(cd, f0[tb] - w0 * cd), min(f1[tb] - w1 * cd, f2[tb] - w2 * cd))
                sc = sc if lo >= zero else neg
                old = best[tb]
                arg[tb] = fc if sc > old else arg[tb]
                best[tb] = max(sc, old)


@numba.njit(cache=True)
def _trial_scores(corr, pen, prefixes, prefix_inv, ext_ptr, last, ext,
                  out):  # pragma: no cover - compiled
    """All tuple scores of one trial, vectorised over the tuples of each prefix.

    -inf: infeasible or holding a blocked atom (pen (Mc,) 0 or -inf).  One lane of
    the blocked kernels gains nothing from vectors.  Same arithmetic as the blocked
    kernels.
    """
    km = prefixes.shape[0]
    b, f = np.empty(km, out.dtype), np.empty(km, out.dtype)
    f[0] = 0.0
    zero = f[0]  # 0 and -inf as the scores' type
    f[0] = -np.inf
    neg = f[0]
    for r in range(prefixes.shape[1]):
        for i in range(km):
            b[i] = corr[prefixes[i, r]]
        for i in range(km):
            fi = prefix_inv[i, 0, r] * b[0]
            for j in range(1, km):
                fi = fi + prefix_inv[i, j, r] * b[j]
            f[i] = fi
        s = b[0] * f[0]
        for i in range(1, km):
            s = s + b[i] * f[i]
        for i in range(km):
            s = s + pen[prefixes[i, r]]
        lo_c, hi_c = ext_ptr[r], ext_ptr[r + 1]
        if km == 2:  # K = 3 unrolled (K = 4 runs blocked, tuple_trials)
            b0, b1, f0, f1 = b[0], b[1], f[0], f[1]
            for c in range(lo_c, hi_c):
                w0, w1 = ext[0, c], ext[1, c]
                rr = corr[last[c]] - (w0 * b0 + w1 * b1)
                cd = rr * ext[2, c]
                lo = min(cd, min(f0 - w0 * cd, f1 - w1 * cd))
                out[c] = s + rr * cd + pen[last[c]] if lo >= zero else neg
        else:
            for c in range(lo_c, hi_c):
                acc = ext[0, c] * b[0]
                for i in range(1, km):
                    acc = acc + ext[i, c] * b[i]
                rr = corr[last[c]] - acc
                cd = rr * ext[km, c]
                lo = cd
                for i in range(km):
                    lo = min(lo, f[i] - ext[i, c] * cd)
                out[c] = s + rr * cd + pen[last[c]] if lo >= zero else neg


@numba.njit(cache=True)
def _first_max(scores, columns, blocked, masked):  # pragma: no cover - compiled
    """(index, value) of the first maximum of scores (0, -inf if all are -inf).

    ``masked``: tuples with a ``blocked`` atom are skipped.
    """
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
def _per_trial(atoms, subset, columns, prefixes, prefix_inv, ext_ptr, ext, near, arcs, data,
               out, col, col2):  # pragma: no cover - compiled
    """:func:`tuple_trials` one trial at a time: all scores, then the first maxima."""
    mc, dt = atoms.shape[0], ext.dtype
    corr, pen = np.empty(mc, dt), np.zeros(mc, dt)
    blocked = np.zeros(mc, np.bool_)
    scores = np.empty(columns.shape[1], dt)
    last = columns[columns.shape[0] - 1]
    px, py = np.empty(2 * data.shape[1] + 1), np.empty(2 * data.shape[1] + 1)
    for i in range(data.shape[0]):
        _correlations(atoms, arcs, data[i], px, py, corr)
        _trial_scores(corr, pen, prefixes, prefix_inv, ext_ptr, last, ext, scores)
        arg, _ = _first_max(scores, columns, blocked, False)
        _write(subset, columns, arg, out[i, col])
        if col2 >= 0:  # the same scores, tuples with an atom in a basin of the best skipped
            _block(near, columns, arg, blocked)
            arg2, best2 = _first_max(scores, columns, blocked, True)
            _write(subset, columns, arg2 if best2 > -np.inf else arg, out[i, col2])


@numba.njit(cache=True)
def _correlations(atoms, arcs, s, px, py, out):  # pragma: no cover - compiled
    """out = atoms @ s: from the ring atoms' arcs when given (non-empty), else directly."""
    if arcs[3].size:
        _arc_correlations(s, arcs, px, py, out)
    else:
        _matvec(atoms, s, out)


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
def tuple_trials(atoms, subset, columns, prefixes, prefix_inv, ext_ptr, ext, near, arcs, data,
                 out, col, col2):  # pragma: no cover - compiled
    """Best feasible K-tuple (K >= 2) of one coarse plan per trial into out[:, col].

    With col2 >= 0, also the best one outside its atoms' basins (``near`` (Mc, Mc))
    into out[:, col2] (the first one again if there is none).  ``arcs``: the coarse
    ring atoms' arcs (:func:`.search._arc_correlations`), or empty arrays.

    Blocks of up to :data:`TUPLE_BLOCK` trials, vectorised over the trials of a block;
    for K <= 3, fewer than :data:`PER_TRIAL_BELOW` trials one at a time
    (:func:`_per_trial`, vectorised over tuples; at K = 4 the blocked kernel is the
    faster even for one lane).  The same tuples either way.
    """
    mc, t = atoms.shape[0], data.shape[0]
    if t < PER_TRIAL_BELOW and columns.shape[0] <= 3:
        _per_trial(atoms, subset, columns, prefixes, prefix_inv, ext_ptr, ext, near, arcs, data,
                   out, col, col2)
        return
    last = columns[columns.shape[0] - 1]
    nb, dt = min(TUPLE_BLOCK, t), ext.dtype
    corr, corr_t = np.empty(mc), np.zeros((mc, nb), dt)
    blocked, pen_t = np.empty(mc, np.bool_), np.zeros((mc, nb), dt)
    best, args = np.empty(nb, dt), np.empty(nb, dt)
    best2, args2 = np.empty(nb, dt), np.empty(nb, dt)
    px, py = np.empty(2 * data.shape[1] + 1), np.empty(2 * data.shape[1] + 1)
    for start in range(0, t, nb):
        m = min(nb, t - start)
        for tb in range(m):
            _correlations(atoms, arcs, data[start + tb], px, py, corr)
            for u in range(mc):
                corr_t[u, tb] = corr[u]
        pen_t[:] = 0.0
        _block_best(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, False, best, args)
        for tb in range(m):
            _write(subset, columns, int(args[tb]), out[start + tb, col])
        if col2 < 0:
            continue
        for tb in range(m):  # (lanes >= m hold a previous block's trials: unused)
            _block(near, columns, int(args[tb]), blocked)
            for u in range(mc):
                pen_t[u, tb] = -np.inf if blocked[u] else 0.0
        _block_best(corr_t, prefixes, prefix_inv, ext_ptr, last, ext, pen_t, True, best2, args2)
        for tb in range(m):
            arg = args2[tb] if best2[tb] > -np.inf else args[tb]
            _write(subset, columns, int(arg), out[start + tb, col2])
