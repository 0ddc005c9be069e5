"""Compiled (numba) configuration scan: twin of :mod:`olsbayes.ml.exact`.

The enumeration of :func:`olsbayes.ml.exact.enumerate_optimum` -- groups of
a arcs and q pins, Gram matrices looked up in the states' table, LDL^T with the
:data:`~olsbayes.ml.exact.RANK_RTOL` rank test, LS solutions, the closed-cell
feasibility test with :data:`~olsbayes.ml.exact.FEAS_RTOL` slack and the
near-best candidates kept for the direct re-ranking -- one configuration at a
time, so a rank-deficient configuration stops at its first small pivot and no
(configurations x p x p) temporaries are built.  Compiled once per machine
(``cache=True``); imported on first use, not with the package.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["scan"]


@numba.njit(cache=True)
def _next_combination(c, n):  # pragma: no cover - compiled
    """Advance the sorted r-subset c of range(n) in place.

    Returns the first position that changed, -1 after the last subset.
    """
    r = c.size
    i = r - 1
    while i >= 0 and c[i] == n - r + i:
        i -= 1
    if i < 0:
        return -1
    c[i] += 1
    for j in range(i + 1, r):
        c[j] = c[j - 1] + 1
    return i


@numba.njit(cache=True)
def _factor_rows(gram, idx, r0, p, rtol, low, ud, inv):  # pragma: no cover - compiled
    """Rows r0..p-1 of the LDL^T of gram[idx, idx] (p x p).

    The leading r0 rows are those of the previous configuration, which shares idx[:r0].

    low: unit lower factor L, ud = L D (below the diagonal), inv = 1 / D.  Returns
    the first rank-deficient row (pivot <= rtol times its diagonal entry), or p.
    """
    for i in range(r0, p):
        gi = idx[i]
        d = gram[gi, gi]
        for j in range(i):
            acc = gram[gi, idx[j]]
            for k in range(j):
                acc -= low[i, k] * ud[j, k]
            ud[i, j] = acc
            low[i, j] = acc * inv[j]
            d -= acc * low[i, j]
        if d <= rtol * gram[gi, gi]:
            return i
        inv[i] = 1.0 / d
    return p


@numba.njit(cache=True)
def _forward(b, t, idx, r0, p, low, inv, z, gp):  # pragma: no cover - compiled
    """Gain b^T G^-1 b of data vector t, b = b[t, idx], by forward substitution L z = b.

    The substitution runs from row r0 on; z[t, :r0] and the prefix gains
    gp[t, :r0 + 1] (gp[t, 0] = 0) are those of the previous configuration, which
    shares its leading rows.
    """
    for i in range(r0, p):
        zi = b[t, idx[i]]
        for k in range(i):
            zi -= low[i, k] * z[t, k]
        z[t, i] = zi
        gp[t, i + 1] = gp[t, i] + zi * zi * inv[i]
    return gp[t, p]


@numba.njit(cache=True)
def _backward(t, p, low, inv, z, x):  # pragma: no cover - compiled
    """The LS solution x = L^-T D^-1 z[t] (p,) after :func:`_forward`."""
    for i in range(p):
        x[i] = z[t, i] * inv[i]
    for i in range(p - 2, -1, -1):
        for k in range(i + 1, p):
            x[i] -= low[k, i] * x[k]


@numba.njit(cache=True)
def _feasible(x, arcs, a, p, units, ftol):  # pragma: no cover - compiled
    """Closed-cell test of a solution x (p,) whose first a sources are arcs."""
    top = 0.0
    for i in range(p):
        top = max(top, abs(x[i]))
    slack = ftol * top
    for i in range(2 * a, p):
        if x[i] < -slack:
            return False
    m = units.shape[0]
    for r in range(a):
        j = arcs[r]
        px, py = x[2 * r], x[2 * r + 1]
        if units[j, 0] * py - units[j, 1] * px < -slack:
            return False
        j1 = (j + 1) % m
        if px * units[j1, 1] - py * units[j1, 0] < -slack:
            return False
    return True


@numba.njit(cache=True)
def _offer(t, gain, states, best, margin, cgain, cstate, count):  # pragma: no cover
    """Keep configuration ``states`` for trial t if within margin of the best gain."""
    if gain > best[t]:
        best[t] = gain
        kept = 0
        for i in range(count[t]):
            if cgain[t, i] >= gain - margin[t]:
                cgain[t, kept] = cgain[t, i]
                cstate[t, kept, :] = cstate[t, i, :]
                kept += 1
        count[t] = kept
    if gain < best[t] - margin[t]:
        return
    slot = count[t]
    if slot == cgain.shape[1]:  # full: replace the weakest if weaker
        slot = np.argmin(cgain[t])
        if cgain[t, slot] >= gain:
            return
    else:
        count[t] += 1
    cgain[t, slot] = gain
    cstate[t, slot, :] = states


@numba.njit(cache=True)
def _scan_group(gram, b, units, a, q, rtol, ftol, count_feasible, out):  # pragma: no cover
    """All configurations of a arcs and q pins; returns their number.

    Consecutive configurations share their leading states (the combinations
    advance from the back), so only the rows from the first changed one are
    refactored and re-substituted; while a rank-deficient leading block is
    unchanged, the configurations are deficient without any arithmetic.
    """
    best, margin, cgain, cstate, count, n_feas = out
    m, n_t, k = units.shape[0], b.shape[0], cstate.shape[2]
    p = 2 * a + q
    arcs, pins = np.arange(a), np.arange(q)
    idx, states = np.empty(p, np.int64), np.full(k, -1, np.int64)
    low, ud, inv, x = np.empty((p, p)), np.empty((p, p)), np.empty(p), np.empty(p)
    z, gp = np.empty((n_t, p)), np.zeros((n_t, p + 1))
    n, frow, zrow, arc0 = 0, 0, 0, 0
    while arc0 >= 0:
        for r in range(a):
            idx[2 * r], idx[2 * r + 1], states[r] = 2 * arcs[r], 2 * arcs[r] + 1, arcs[r]
        pins[:] = np.arange(q)
        r0 = 2 * arc0  # first row that differs from the previous configuration
        while r0 >= 0:
            n += 1
            for r in range(q):
                idx[2 * a + r], states[a + r] = 2 * m + pins[r], m + pins[r]
            zrow = min(zrow, r0)
            if r0 <= frow:  # else the deficient leading rows are unchanged
                frow = _factor_rows(gram, idx, r0, p, rtol, low, ud, inv)
                if frow == p:
                    for t in range(n_t):
                        gain = _forward(b, t, idx, zrow, p, low, inv, z, gp)
                        if not count_feasible and gain < best[t] - margin[t]:
                            continue  # _offer would drop it: no solution needed
                        _backward(t, p, low, inv, z, x)
                        if _feasible(x, arcs, a, p, units, ftol):
                            n_feas[t] += 1
                            _offer(t, gain, states, best, margin, cgain, cstate, count)
                    zrow = p
            i = _next_combination(pins, m)
            r0 = 2 * a + i if i >= 0 else -1
        arc0 = _next_combination(arcs, m)
    return n


def scan(gram: np.ndarray, b: np.ndarray, units: np.ndarray, k: int, margin: np.ndarray,
         rtol: float, ftol: float, max_candidates: int, count_feasible: bool = True) -> tuple:
    """Every configuration of at most k states; near-best feasible ones per trial.

    Parameters
    ----------
    gram : ndarray, shape (3M, 3M)
        Inner products of the state columns (arc j at 2j, 2j+1, pin j at 2M + j).
    b : ndarray, shape (T, 3M)
        Column-data inner products A^T s.
    units : ndarray, shape (M, 2)
        Crossing directions (cos c, sin c).
    k : int
        Largest number of states.
    margin : ndarray, shape (T,)
        Gains within margin of the best are kept as candidates.
    rtol, ftol : float
        Rank and feasibility tolerances.
    max_candidates : int
        Candidates kept per trial.
    count_feasible : bool
        Count the feasible configurations.  Without the count, the solution and
        feasibility test of a configuration whose gain is already below the best
        minus the margin (never a candidate) are skipped: the same candidates.

    Returns
    -------
    cgain : ndarray, shape (T, max_candidates)
        Candidate gains b^T G^-1 b (the empty configuration's is 0).
    cstate : ndarray of int, shape (T, max_candidates, k)
        Candidate states: arc j -> j, pin j -> M + j, unused -> -1.
    count : ndarray of int, shape (T,)
        Candidates per trial.
    n_feasible : ndarray of int, shape (T,), or None
        Feasible full-rank configurations (the empty one included); None without
        ``count_feasible``.
    n_configurations : int
        Configurations enumerated (the empty one included).
    """
    n_t, m = b.shape[0], units.shape[0]
    cgain = np.zeros((n_t, max_candidates))
    cstate = np.full((n_t, max_candidates, k), -1, dtype=np.int64)
    count = np.ones(n_t, dtype=np.int64)  # the empty configuration, gain 0
    out = (np.zeros(n_t), np.ascontiguousarray(margin, dtype=float), cgain, cstate, count,
           np.ones(n_t, dtype=np.int64))
    n_conf = 1
    g, bb, u = (np.ascontiguousarray(v, dtype=float) for v in (gram, b, units))
    for a in range(min(k, m) + 1):
        for q in range(1 if a == 0 else 0, min(k - a, m) + 1):
            n_conf += _scan_group(g, bb, u, a, q, rtol, ftol, bool(count_feasible), out)
    return cgain, cstate, count, out[5] if count_feasible else None, n_conf
