"""Numpy reference of the configuration scan of :func:`olsbayes.ml.exact.enumerate_optimum`.

Vectorised over chunks of configurations of a arcs and q pins: Gram matrices
gathered from the states' table, a batched LDL^T with a rank test, LS solutions
for all data vectors at once (the factorisations are shared by a batch), the
closed-cell feasibility test, and the near-best candidates kept for the direct
re-ranking.  :mod:`olsbayes.ml._numba.exact` runs the same scan compiled, one
configuration at a time; both return the same (see :func:`scan`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ["scan"]

#: Configurations x data vectors x parameters per chunk (~16 MiB of float64).
_CHUNK_TERMS = 1 << 21


def _combinations(n: int, r: int) -> np.ndarray:
    """All r-subsets of range(n) as rows, shape (C(n, r), r), int64."""
    if r == 0:
        return np.zeros((1, 0), dtype=np.int64)
    flat = itertools.chain.from_iterable(itertools.combinations(range(n), r))
    return np.fromiter(flat, dtype=np.int64).reshape(-1, r)


def _ldl(g: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched LDL^T of Gram matrices with a rank test.

    Parameters
    ----------
    g : ndarray, shape (C, p, p)
        Symmetric positive semi-definite matrices.
    rtol : float
        Relative pivot threshold of the rank test.

    Returns
    -------
    low : ndarray, shape (C, p, p)
        Unit lower-triangular factors (strict lower part used).
    piv : ndarray, shape (C, p)
        Pivots D (set to 1 where rank-deficient).
    ok : ndarray of bool, shape (C,)
        Full rank: every pivot above ``rtol`` times its diagonal entry.
    """
    n, p = g.shape[:2]
    low = np.zeros_like(g)
    piv = np.empty((n, p))
    ok = np.ones(n, dtype=bool)
    for j in range(p):
        w = low[:, j, :j] * piv[:, :j]  # L_jk D_k
        dj = g[:, j, j] - np.einsum("ck,ck->c", w, low[:, j, :j])
        bad = dj <= rtol * g[:, j, j]
        ok &= ~bad
        piv[:, j] = np.where(bad, 1.0, dj)
        if j + 1 < p:
            num = g[:, j + 1 :, j] - np.einsum("cik,ck->ci", low[:, j + 1 :, :j], w)
            low[:, j + 1 :, j] = num / piv[:, j, None]
    return low, piv, ok


def _solve(low: np.ndarray, piv: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LS solutions x (T, C, p) and explained sums b^T G^-1 b (T, C) for b (T, C, p)."""
    p = piv.shape[1]
    z = np.empty_like(b)
    for i in range(p):
        z[..., i] = b[..., i] - np.einsum("ck,tck->tc", low[:, i, :i], z[..., :i])
    explained = np.einsum("tcp,tcp->tc", z * z, np.broadcast_to(1.0 / piv, z.shape))
    x = z / piv
    for i in range(p - 2, -1, -1):
        x[..., i] -= np.einsum("ck,tck->tc", low[:, i + 1 :, i], x[..., i + 1 :])
    return x, explained


def _feasible(x: np.ndarray, arcs: np.ndarray, units: np.ndarray, ftol: float) -> np.ndarray:
    """Whether each LS solution x (T, C, p) lies in its cell (slack ftol); arcs (C, a)."""
    a = arcs.shape[1]
    scale = ftol * np.max(np.abs(x), axis=-1, initial=0.0)  # (T, C)
    ok = np.all(x[..., 2 * a :] >= -scale[..., None], axis=-1)
    m = units.shape[0]
    for r in range(a):
        px, py = x[..., 2 * r], x[..., 2 * r + 1]
        u0, u1 = units[arcs[:, r]], units[(arcs[:, r] + 1) % m]
        ok &= u0[:, 0] * py - u0[:, 1] * px >= -scale
        ok &= px * u1[:, 1] - py * u1[:, 0] >= -scale
    return ok


@dataclass
class _Best:
    """Running near-best configurations per data vector (internal, mutable)."""

    gain: np.ndarray  # (T,) best gain b^T G^-1 b (chi^2 = s.s - gain)
    margin: np.ndarray  # (T,)
    cands: list  # (T,) lists of (gain, states (K,))
    n_feasible: np.ndarray  # (T,)
    k: int
    m: int
    max_candidates: int

    def offer(self, t: int, gain: np.ndarray, arcs: np.ndarray, pins: np.ndarray) -> None:
        """Add trial t's feasible configurations (gains (C,)) that are near-best."""
        top = max(self.gain[t], float(gain.max(initial=-np.inf)))
        if top > self.gain[t]:
            self.gain[t] = top
            self.cands[t] = [c for c in self.cands[t] if c[0] >= top - self.margin[t]]
        for i in np.flatnonzero(gain >= top - self.margin[t]):
            states = np.full(self.k, -1, dtype=np.int64)
            states[: arcs.shape[1]] = arcs[i]
            states[arcs.shape[1] : arcs.shape[1] + pins.shape[1]] = self.m + pins[i]
            self.cands[t].append((gain[i], states))
        if len(self.cands[t]) > self.max_candidates:  # e.g. all-zero data: all tie
            self.cands[t].sort(key=lambda cand: -cand[0])
            del self.cands[t][self.max_candidates :]


def _scan_group(gram: np.ndarray, b: np.ndarray, best: _Best, units: np.ndarray,
                a: int, q: int, rtol: float, ftol: float) -> int:
    """Enumerate the configurations of a arcs and q pins, offer them to ``best``.

    gram (3M, 3M) and b (T, 3M): the states' Gram table and A^T s; units (M, 2)
    the crossing directions.  Returns the number of configurations.
    """
    m = units.shape[0]
    arc_sets, pin_sets = _combinations(m, a), _combinations(m, q)
    n_total, n_pin = arc_sets.shape[0] * pin_sets.shape[0], pin_sets.shape[0]
    p, n_t = 2 * a + q, b.shape[0]
    step = max(64, _CHUNK_TERMS // (p * max(p, n_t)))
    for start in range(0, n_total, step):
        flat = np.arange(start, min(start + step, n_total))
        arcs, pins = arc_sets[flat // n_pin], pin_sets[flat % n_pin]
        idx = np.concatenate([np.stack([2 * arcs, 2 * arcs + 1], -1).reshape(len(flat), 2 * a),
                              2 * m + pins], axis=1)
        low, piv, ok = _ldl(gram[idx[:, :, None], idx[:, None, :]], rtol)
        arcs, pins, idx, low, piv = arcs[ok], pins[ok], idx[ok], low[ok], piv[ok]
        x, gain = _solve(low, piv, b[:, idx])
        feas = _feasible(x, arcs, units, ftol)
        best.n_feasible += feas.sum(axis=1)
        for t in range(n_t):
            best.offer(t, gain[t, feas[t]], arcs[feas[t]], pins[feas[t]])
    return n_total


def scan(gram: np.ndarray, b: np.ndarray, units: np.ndarray, k: int, margin: np.ndarray,
         rtol: float, ftol: float, max_candidates: int) -> tuple:
    """Every configuration of at most k states; near-best feasible ones per trial.

    Same arguments and returns as :func:`olsbayes.ml._numba.exact.scan`
    (candidates in another order).
    """
    n_t, m = b.shape[0], units.shape[0]
    best = _Best(gain=np.zeros(n_t), margin=np.asarray(margin, dtype=float),
                 cands=[[(0.0, np.full(k, -1, dtype=np.int64))] for _ in range(n_t)],
                 n_feasible=np.ones(n_t, dtype=np.int64), k=k, m=m,
                 max_candidates=max_candidates)
    n_conf = 1  # the empty configuration (all sources absent)
    for a in range(min(k, m) + 1):
        for q in range(1 if a == 0 else 0, min(k - a, m) + 1):
            n_conf += _scan_group(gram, b, best, units, a, q, rtol, ftol)
    cgain = np.zeros((n_t, max_candidates))
    cstate = np.full((n_t, max_candidates, k), -1, dtype=np.int64)
    count = np.array([len(c) for c in best.cands], dtype=np.int64)
    for t, cands in enumerate(best.cands):
        for i, (gain, states) in enumerate(cands):
            cgain[t, i], cstate[t, i] = gain, states
    return cgain, cstate, count, best.n_feasible, n_conf
