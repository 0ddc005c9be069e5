"""Compiled (numba) correlations of sphere atoms, one from another over a spanning tree.

A sphere atom of the clipped cosine is ``g_a[n] = max(u_a . n_n, 0)``: its
correlation with readings s is ``u_a . V_a`` with ``V_a = sum s_n n_n`` over the
sub-sensors the atom lights (a hemisphere of them).  Two nearby atoms light
nearly the same sub-sensors -- they differ only in the thin lune between their
horizons -- so ``V`` of an atom follows from ``V`` of a neighbour by adding the
sub-sensors it lights and the neighbour does not, and subtracting the converse.
Over a minimum spanning tree of the atoms (angular distance) the correlations of
all M atoms cost O(M + L), L the total size of those differences: about
``M N delta / pi`` for a grid of spacing delta, against O(M N) for ``G @ s``
(a 2048-direction grid, N = 1000: L ~ 24 M, a fifth of the work).

A tree is the tuple ``(order, parent, ptr, sensor, w, u)``: the atoms in the
tree's order (each after its parent), each atom's parent (-1: the root, whose
difference is its whole lit set), the CSR pointers (M + 1) of the differences in
that order, the sub-sensor of each entry and its signed normal ``w`` (L, 3)
(+n: lit by the atom only, -n: by the parent only), and the atoms' unit
directions ``u`` (M, 3).  Empty arrays: no tree (correlate with the atoms).

An entry costs about eight times an atom entry of ``G @ s`` (a gather and three
multiply-adds against one vectorised multiply-add), so a tree pays where L is
below about M N / 8: on the fine grids, not on coarse subsets of them.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["hemisphere_tree", "tree_correlations"]


@numba.njit(cache=True)
def _prim(u):  # pragma: no cover - compiled
    """Prim's minimum spanning tree of the unit rows of u (M, 3) by angle: (order, parent)."""
    m = u.shape[0]
    done = np.zeros(m, np.bool_)
    near, parent, order = np.full(m, -2.0), np.full(m, -1, np.int64), np.empty(m, np.int64)
    cur = 0
    for i in range(m):
        done[cur], order[i] = True, cur
        nxt, top = -1, -3.0
        for b in range(m):
            if done[b]:
                continue
            d = u[cur, 0] * u[b, 0] + u[cur, 1] * u[b, 1] + u[cur, 2] * u[b, 2]
            if d > near[b]:
                near[b], parent[b] = d, cur
            if near[b] > top:
                top, nxt = near[b], b
        cur = nxt
    return order, parent


@numba.njit(cache=True)
def _differs(g, a, p, q):  # pragma: no cover - compiled
    """Whether sub-sensor q is in atom a's difference from its parent p (lit by one only)."""
    lit = g[a, q] > 0.0
    return lit if p < 0 else lit != (g[p, q] > 0.0)


@numba.njit(cache=True)
def _clipped_cosine(g, u, nrm, tol):  # pragma: no cover - compiled
    """Whether every atom of g (M, N) is ``max(u . n, 0)`` to tol."""
    for a in range(g.shape[0]):
        for q in range(g.shape[1]):
            c = u[a, 0] * nrm[q, 0] + u[a, 1] * nrm[q, 1] + u[a, 2] * nrm[q, 2]
            if abs(max(c, 0.0) - g[a, q]) > tol:
                return False
    return True


@numba.njit(cache=True)
def hemisphere_tree(g, u, nrm, tol, max_entries):  # pragma: no cover - compiled
    """The tree of the atoms g (M, N) with unit directions u (M, 3), normals nrm (N, 3).

    Returns ``(ok, order, parent, ptr, sensor, w)``; ok is False (and the arrays
    empty) if an atom differs from ``max(u . n, 0)`` by more than tol (tol < 0:
    not checked), or the differences exceed ``max_entries`` entries.
    """
    m, n = g.shape
    empty_i, empty_w = np.zeros(0, np.int64), np.zeros((0, 3))
    if tol >= 0.0 and not _clipped_cosine(g, u, nrm, tol):
        return False, empty_i, empty_i, empty_i, empty_i, empty_w
    order, parent = _prim(u)
    ptr = np.zeros(m + 1, np.int64)
    for i in range(m):
        a = order[i]
        c = 0
        for q in range(n):
            c += _differs(g, a, parent[a], q)
        ptr[i + 1] = ptr[i] + c
        if ptr[i + 1] > max_entries:
            return False, empty_i, empty_i, empty_i, empty_i, empty_w
    sensor, w = np.empty(ptr[m], np.int64), np.empty((ptr[m], 3))
    for i in range(m):
        a, c = order[i], ptr[i]
        for q in range(n):
            if _differs(g, a, parent[a], q):
                sign = 1.0 if g[a, q] > 0.0 else -1.0
                sensor[c] = q
                for d in range(3):
                    w[c, d] = sign * nrm[q, d]
                c += 1
    return True, order, parent, ptr, sensor, w


@numba.njit(cache=True, fastmath={"reassoc"})
def tree_correlations(s, tree, v, out):  # pragma: no cover - compiled
    """out = g @ s for the atoms of ``tree`` (module docstring); v (M, 3) workspace."""
    order, parent, ptr, sensor, w, u = tree
    for i in range(order.size):
        a, p = order[i], parent[order[i]]
        if p < 0:
            vx, vy, vz = 0.0, 0.0, 0.0
        else:
            vx, vy, vz = v[p, 0], v[p, 1], v[p, 2]
        for c in range(ptr[i], ptr[i + 1]):
            x = s[sensor[c]]
            vx += x * w[c, 0]
            vy += x * w[c, 1]
            vz += x * w[c, 2]
        v[a, 0], v[a, 1], v[a, 2] = vx, vy, vz
        out[a] = u[a, 0] * vx + u[a, 1] * vy + u[a, 2] * vz
