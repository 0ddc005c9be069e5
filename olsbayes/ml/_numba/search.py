"""Compiled (numba) grid search: twin of :mod:`olsbayes.ml.fast.search`.

Runs, one trial at a time, the stages of the fast fit's search -- orthogonal
matching pursuit, alternating projection, runner-up positions of each source and
the least-squares intensities of every candidate (the exhaustive K-tuple scan of
each coarse subset is :mod:`.tuples`) -- with the same scores, tie-breaking
(first maximum) and stopping rules as the numpy reference the tests hold it
against.  The orthonormal bases of the chosen atoms come from modified
Gram–Schmidt instead of Householder QR and sums may be reassociated, so scores
differ from the numpy ones by rounding only.  For one data vector numpy's
per-call overhead would be most of the search's cost.
"""

from __future__ import annotations

import numba
import numpy as np

from ..atoms import NEIGHBOUR
from .hemispheres import tree_correlations
from .linalg import _solve

__all__ = ["arc_gram", "intensities_trials", "neighbours", "ring_arcs", "search_trials"]


@numba.njit(cache=True, fastmath={"reassoc"})
def _matvec(g, v, out):  # pragma: no cover - compiled
    """out = g @ v for g (M, N), v (N,)."""
    for m in range(g.shape[0]):
        acc = 0.0
        for n in range(g.shape[1]):
            acc += g[m, n] * v[n]
        out[m] = acc


@numba.njit(cache=True)
def _argmax(v):  # pragma: no cover - compiled
    """Index of the first maximum (as numpy.argmax; 0 when all are -inf)."""
    best, arg = v[0], 0
    for i in range(1, v.size):
        if v[i] > best:
            best, arg = v[i], i
    return arg


@numba.njit(cache=True, fastmath={"reassoc"})
def _basis(g, idx, skip, q, coef):  # pragma: no cover - compiled
    """Orthonormal rows q[:r] spanning the atoms g[idx[j]], j != skip; returns r.

    Modified Gram–Schmidt with one reorthogonalisation pass; an atom already in
    the span of the previous ones (to 1e-12 of its norm) adds no row.  coef[i, j]:
    q[i] as a combination of the atoms g[idx[j]] (for :func:`_scores`' Gram route).
    """
    r = 0
    n = g.shape[1]
    for j in range(idx.size):
        if j == skip:
            continue
        v = q[r]
        for u in range(idx.size):
            coef[r, u] = 0.0
        coef[r, j] = 1.0
        norm0 = 0.0
        for t in range(n):
            v[t] = g[idx[j], t]
            norm0 += v[t] * v[t]
        for _ in range(2):
            for i in range(r):
                c = 0.0
                for t in range(n):
                    c += q[i, t] * v[t]
                for t in range(n):
                    v[t] -= c * q[i, t]
                for u in range(idx.size):
                    coef[r, u] -= c * coef[i, u]
        norm = 0.0
        for t in range(n):
            norm += v[t] * v[t]
        if norm <= 1e-24 * norm0 or norm == 0.0:
            continue
        inv = 1.0 / np.sqrt(norm)
        for t in range(n):
            v[t] *= inv
        for u in range(idx.size):
            coef[r, u] *= inv
        r += 1
    return r


@numba.njit(cache=True)
def _scores(g, gram, gnorm2, gs, s, idx, q, coef, r, cg, cs, out):  # pragma: no cover
    """Residual-sum-of-squares drop of every atom given the r bases q (search._scores).

    The atoms' components along q, g @ q[j], come from the Gram matrix of the
    atoms (M, M) when given (``gram.shape[0] > 0``): combinations of r rows of
    it, O(r K M) instead of O(r N M).
    """
    m = g.shape[0]
    for j in range(r):
        if gram.shape[0]:
            acc = 0.0
            for i in range(m):
                cg[j, i] = 0.0
            for u in range(idx.size):
                w = coef[j, u]
                if w != 0.0:
                    acc += w * gs[idx[u]]
                    for i in range(m):
                        cg[j, i] += w * gram[idx[u], i]
            cs[j] = acc
        else:
            _matvec(g, q[j], cg[j])
            cs[j] = 0.0
            for t in range(s.size):
                cs[j] += q[j, t] * s[t]
    for i in range(m):
        num, den = gs[i], gnorm2[i]
        for j in range(r):
            num -= cg[j, i] * cs[j]
            den -= cg[j, i] * cg[j, i]
        ok = num > 0.0 and den > 1e-8 * gnorm2[i]
        out[i] = num * num / den if ok else -np.inf


@numba.njit(cache=True)
def _given_others(g, gram, gnorm2, gs, s, idx, j, w, out):  # pragma: no cover - compiled
    """Scores of source j's atom given the other atoms idx (all but j); w = (q, coef, cg, cs)."""
    q, coef, cg, cs = w
    r = _basis(g, idx, j, q, coef)
    _scores(g, gram, gnorm2, gs, s, idx, q, coef, r, cg, cs, out)


@numba.njit(cache=True)
def _pursue_and_alternate(g, gram, gnorm2, gs, s, k, max_sweeps, w, sc):  # pragma: no cover
    """Pursuit then alternating projection (search._pursuit / _alternate).

    sc (K, M) ends as each source's scores given the others at the returned atoms.
    """
    idx = np.zeros(k, np.int64)
    none = np.int64(-1)  # a variable, not the literal: one compiled _given_others
    for step in range(k):
        _given_others(g, gram, gnorm2, gs, s, idx[:step], none, w, sc[0])
        idx[step] = _argmax(sc[0])
    if k == 1:
        return idx
    for _ in range(max_sweeps):
        changed = False
        for j in range(k):
            _given_others(g, gram, gnorm2, gs, s, idx, j, w, sc[j])
            best = _argmax(sc[j])
            if sc[j, best] > sc[j, idx[j]] * (1 + 1e-12):
                idx[j] = best
                changed = True
        if not changed:
            return idx
    for j in range(k):  # no converged sweep: the scores at the final atoms
        _given_others(g, gram, gnorm2, gs, s, idx, j, w, sc[j])
    return idx


@numba.njit(cache=True, fastmath={"reassoc"})
def _unit_dot(unit, a, b):  # pragma: no cover - compiled
    """Correlation of the normalised atoms a and b."""
    acc = 0.0
    for t in range(unit.shape[1]):
        acc += unit[a, t] * unit[b, t]
    return acc


@numba.njit(cache=True)
def neighbours(unit):  # pragma: no cover - compiled
    """CSR lists (indptr, indices) of the atoms within each atom's basin (> NEIGHBOUR)."""
    m = unit.shape[0]
    indptr = np.zeros(m + 1, np.int64)
    for a in range(m):
        for b in range(m):
            indptr[a + 1] += _unit_dot(unit, a, b) > NEIGHBOUR
    for a in range(m):
        indptr[a + 1] += indptr[a]
    indices = np.empty(indptr[m], np.int64)
    for a in range(m):
        c = indptr[a]
        for b in range(m):
            if _unit_dot(unit, a, b) > NEIGHBOUR:
                indices[c] = b
                c += 1
    return indptr, indices


@numba.njit(cache=True)
def _runners_up(unit, indptr, indices, base, n_alt, sc, out, first):  # pragma: no cover
    """Runner-up atoms of each source outside the taken basins (search._alternatives).

    The basin of an atom comes from the CSR lists of :func:`neighbours` when given
    (indptr non-empty), else from its correlations with every atom.
    """
    k, m = base.size, unit.shape[0]
    c = first
    for j in range(k):
        taken = base[j]
        for _ in range(n_alt):
            if indptr.size:
                for q in range(indptr[taken], indptr[taken + 1]):
                    sc[j, indices[q]] = -np.inf
            else:
                for i in range(m):
                    if _unit_dot(unit, taken, i) > NEIGHBOUR:
                        sc[j, i] = -np.inf
            taken = _argmax(sc[j])
            out[c] = base
            if np.isfinite(sc[j, taken]):
                out[c, j] = taken
            c += 1


@numba.njit(cache=True)
def _arc_correlations(s, arcs, px, py, out):  # pragma: no cover - compiled
    """out = g @ s for ring atoms whose lit sub-sensors are arcs, in O(M + N).

    arcs = (order, nx, ny, lo, cnt, ct, st): the sub-sensors in angular order and
    their normals' components in that order; per atom the first lit sub-sensor (in
    that order), their count and the atom's direction (cos, sin).  An atom's
    correlation is ``ct * sum(s nx) + st * sum(s ny)`` over its arc: differences of
    prefix sums px, py (2 N + 1) over the sub-sensors taken twice round.
    """
    order, nx, ny, lo, cnt, ct, st = arcs
    n = order.size
    px[0], py[0] = 0.0, 0.0
    for j in range(2 * n):
        q = j if j < n else j - n
        v = s[order[q]]
        px[j + 1] = px[j] + v * nx[q]
        py[j + 1] = py[j] + v * ny[q]
    for a in range(out.size):
        b, e = lo[a], lo[a] + cnt[a]
        out[a] = ct[a] * (px[e] - px[b]) + st[a] * (py[e] - py[b])


@numba.njit(cache=True)
def arc_gram(arcs, out):  # pragma: no cover - compiled
    """out = g @ g.T (M, M) for ring atoms whose lit sub-sensors are arcs, in O(M^2 + N).

    Two atoms' product is ``(ca nx + sa ny)(cb nx + sb ny)`` summed over the
    sub-sensors both light, one or two runs in angular order: the intersections
    of atom a's arc with atom b's arc shifted by -N, 0 and N turns (an arc holds at
    most N sub-sensors, so no sub-sensor counts twice), each a difference of
    prefix sums of nx^2, nx ny and ny^2 over the sub-sensors taken twice round.
    """
    order, nx, ny, lo, cnt, ct, st = arcs
    n, m = order.size, lo.size
    pxx, pxy, pyy = np.zeros(2 * n + 1), np.zeros(2 * n + 1), np.zeros(2 * n + 1)
    for j in range(2 * n):
        q = j if j < n else j - n
        pxx[j + 1] = pxx[j] + nx[q] * nx[q]
        pxy[j + 1] = pxy[j] + nx[q] * ny[q]
        pyy[j + 1] = pyy[j] + ny[q] * ny[q]
    for a in range(m):
        la, ea = lo[a], lo[a] + cnt[a]
        for b in range(a, m):
            xx = xy = yy = 0.0
            for shift in (-n, 0, n):
                b0, e0 = max(la, lo[b] + shift), min(ea, lo[b] + cnt[b] + shift)
                if e0 > b0:
                    xx += pxx[e0] - pxx[b0]
                    xy += pxy[e0] - pxy[b0]
                    yy += pyy[e0] - pyy[b0]
            v = ct[a] * ct[b] * xx + (ct[a] * st[b] + st[a] * ct[b]) * xy + st[a] * st[b] * yy
            out[a, b] = v
            out[b, a] = v


@numba.njit(cache=True)
def ring_arcs(g, order, nx, ny, ct, st, tol, lo, cnt):  # pragma: no cover - compiled
    """Each atom's lit sub-sensors (g > 0) as one run in ``order``: lo, cnt (M,).

    False if an atom of g (M, N) differs by more than tol from the clipped cosine
    ``max(ct nx + st ny, 0)`` of its direction (ct, st) against the normals (nx, ny)
    taken in ``order``, or lights more than one run of them (circularly).
    """
    n = order.size
    for a in range(g.shape[0]):
        rises, count, first = 0, 0, 0
        prev = g[a, order[n - 1]] > 0.0
        for q in range(n):
            v = g[a, order[q]]
            if abs(max(ct[a] * nx[q] + st[a] * ny[q], 0.0) - v) > tol:
                return False
            lit = v > 0.0
            if lit:
                count += 1
                if not prev:
                    rises += 1
                    first = q
            prev = lit
        if rises > 1 or (rises == 0 and 0 < count < n):
            return False
        lo[a], cnt[a] = (first if rises == 1 else 0), count
    return True


@numba.njit(cache=True)
def search_trials(g, gram, gnorm2, unit, indptr, indices, arcs, tree, data, k, max_sweeps,
                  n_alt, out):  # pragma: no cover - compiled
    """Pursuit + alternation + runners-up for every trial: out (T, C, K), rows 0..K n_alt.

    gram: the atoms' Gram matrix (M, M), or (0, 0) to project with the atoms
    themselves.  arcs: the ring atoms' arcs (:func:`_arc_correlations`); tree: the
    sphere atoms' tree (:func:`.hemispheres.tree_correlations`); empty arrays: correlate
    with the atoms themselves.  The remaining rows of ``out`` (tuple candidates)
    are left for :func:`tuple_trials`.
    """
    m, n = g.shape
    kk = max(k, 1)
    gs, sc = np.empty(m), np.empty((k, m))
    px, py = np.empty(2 * n + 1), np.empty(2 * n + 1)
    v = np.empty((m if tree[0].size else 0, 3))
    w = (np.empty((kk, n)), np.zeros((kk, kk)), np.empty((kk, m)), np.empty(kk))
    for i in range(data.shape[0]):
        s = data[i]
        if arcs[3].size:
            _arc_correlations(s, arcs, px, py, gs)
        elif tree[0].size:
            tree_correlations(s, tree, v, gs)
        else:
            _matvec(g, s, gs)
        base = _pursue_and_alternate(g, gram, gnorm2, gs, s, k, max_sweeps, w, sc)
        out[i, 0] = base
        _runners_up(unit, indptr, indices, base, n_alt, sc, out[i], 1)


@numba.njit(cache=True, fastmath={"reassoc"})
def intensities_trials(g, data, idx, inten, rss):  # pragma: no cover - compiled
    """Least-squares intensities (T, C, K), clipped at 0, and RSS (search._intensities)."""
    t, c, k = idx.shape
    n = g.shape[1]
    ata, lu, rhs, coef = np.empty((k, k)), np.empty((k, k)), np.empty(k), np.empty(k)
    for i in range(t):
        ss = 0.0
        for u in range(n):
            ss += data[i, u] * data[i, u]
        for j in range(c):
            tr = 0.0
            for a in range(k):
                acc = 0.0
                for u in range(n):
                    acc += g[idx[i, j, a], u] * data[i, u]
                rhs[a] = acc
                for b in range(k):
                    acc = 0.0
                    for u in range(n):
                        acc += g[idx[i, j, a], u] * g[idx[i, j, b], u]
                    ata[a, b] = acc
                tr += ata[a, a]
            for a in range(k):
                for b in range(k):
                    lu[a, b] = ata[a, b] + (1e-10 * tr if a == b else 0.0) + 1e-300
            _solve(lu, rhs, coef)
            drop = 0.0
            for a in range(k):
                drop += rhs[a] * coef[a]
                inten[i, j, a] = max(coef[a], 0.0)
            rss[i, j] = ss - drop
