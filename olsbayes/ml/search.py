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

import numpy as np

__all__ = ["grid_search"]

_CHUNK = 512


def _scores(g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Residual-sum-of-squares drop of every atom given bases q, shape (T, M).

    g (M, N), gnorm2 (M,), s (T, N), q (T, N, k) orthonormal columns (k may be 0).
    """
    num = s @ g.T  # (T, M)
    den = np.broadcast_to(gnorm2, num.shape).copy()
    if q.shape[2]:
        cg = np.einsum("mn,tnk->tmk", g, q)  # (T, M, k)
        cs = np.einsum("tn,tnk->tk", s, q)
        num = num - np.einsum("tmk,tk->tm", cg, cs)
        den = den - np.einsum("tmk,tmk->tm", cg, cg)
    ok = (num > 0) & (den > 1e-8 * gnorm2)
    return np.where(ok, num**2 / np.where(ok, den, 1.0), -np.inf)


def _basis(g: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Orthonormal basis (T, N, k) of the atoms idx (T, k)."""
    if idx.shape[1] == 0:
        return np.zeros((idx.shape[0], g.shape[1], 0))
    a = np.swapaxes(g[idx], 1, 2)  # (T, N, k)
    q, _ = np.linalg.qr(a)
    return q


def _search_chunk(
    g: np.ndarray, gnorm2: np.ndarray, s: np.ndarray, k: int, max_sweeps: int
) -> tuple[np.ndarray, int]:
    t = s.shape[0]
    idx = np.zeros((t, 0), dtype=np.int64)
    rows = np.arange(t)
    for _ in range(k):  # matching pursuit
        sc = _scores(g, gnorm2, s, _basis(g, idx))
        idx = np.column_stack([idx, np.argmax(sc, axis=1)])
    sweeps = 0
    for sweeps in range(1, max_sweeps + 1 if k > 1 else 1):  # alternating projection
        changed = np.zeros(t, bool)
        for j in range(k):
            others = np.delete(idx, j, axis=1)
            sc = _scores(g, gnorm2, s, _basis(g, others))
            best = np.argmax(sc, axis=1)
            better = sc[rows, best] > sc[rows, idx[:, j]] * (1 + 1e-12)
            changed |= better
            idx[:, j] = np.where(better, best, idx[:, j])
        if not changed.any():
            break
    return idx, sweeps


def _intensities(g: np.ndarray, s: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Least-squares intensities of the chosen atoms, clipped at 0, shape (T, K)."""
    a = g[idx]  # (T, K, N)
    ata = a @ np.swapaxes(a, 1, 2)
    ridge = 1e-10 * np.trace(ata, axis1=1, axis2=2)[:, None, None] * np.eye(idx.shape[1])
    rhs = np.einsum("tkn,tn->tk", a, s)
    return np.maximum(np.linalg.solve(ata + ridge, rhs[..., None])[..., 0], 0.0)


def grid_search(
    g: np.ndarray, data: np.ndarray, k: int, max_sweeps: int = 8
) -> tuple[np.ndarray, np.ndarray, int]:
    """Best K-atom explanation of every data vector.

    Parameters
    ----------
    g : ndarray, shape (M, N)
        Atom responses (unit intensity).
    data : ndarray, shape (T, N)
    k : int
        Number of sources.
    max_sweeps : int
        Maximum alternating-projection sweeps.

    Returns
    -------
    idx : ndarray of int, shape (T, K)
        Chosen atoms.
    intensity : ndarray, shape (T, K)
        Their non-negative least-squares intensities (clipped).
    sweeps : int
        Largest number of sweeps used in a chunk.
    """
    gnorm2 = np.einsum("mn,mn->m", g, g)
    idx_all, used = [], 0
    for start in range(0, data.shape[0], _CHUNK):
        idx, sw = _search_chunk(g, gnorm2, data[start : start + _CHUNK], k, max_sweeps)
        idx_all.append(idx)
        used = max(used, sw)
    idx = np.concatenate(idx_all, axis=0)
    return idx, _intensities(g, data, idx), used
