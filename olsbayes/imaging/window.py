"""Exact Gibbs moves along the slow directions of local windows of pixels.

Model ``y = A I + e``, ``e ~ N(0, sigma^2 1)``, intensities in the box
``0 <= I <= i_max`` (``i_max`` may be inf) under a flat prior.

Single-site Gibbs moves one pixel at a time; on an ill-posed imaging design the
posterior is long and thin along combinations of neighbouring pixels that the
array barely sees (local checkerboards and smooth trades of intensity), and
coordinate moves crawl along them.  For a window ``B`` of neighbouring pixels
the eigenvectors ``v`` of ``A_B^T A_B`` with small eigenvalues ``lambda`` are
those slow directions, exactly null where the array cannot see a local
pattern.  Along ``I + t v`` (``v`` zero outside ``B``) the posterior of ``t``
is exactly

    p(t) ∝ exp(t (A v)·r / sigma^2 - lambda t^2 / (2 sigma^2))

on the chord where ``I + t v`` stays in the box (``r`` the residual): a
truncated normal, or the exponentially tilted uniform where ``lambda`` is so
small that the quadratic term is negligible on the chord (relative density
error < 1e-8, as in :mod:`olsbayes.imaging.eigen`), both drawn by inversion in
compiled code (:mod:`olsbayes.imaging._window_kernel`).  Each move is an exact
Gibbs draw along a fixed direction, so it leaves the posterior invariant; the
residual update costs O(N + |B|) per chain.  The directions depend on the
design only and are computed once per design (:func:`window_moves`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WindowMoves", "combine", "coordinate_moves", "line_moves", "window_moves",
           "window_sweep"]

_ZERO = 1e-9  # direction components below this (relative) are set to exactly zero


@dataclass(frozen=True)
class WindowMoves:
    """Directions of the window moves (M of them).

    Attributes
    ----------
    index : ndarray of int, shape (M, w)
        Pixels of each direction's window.
    vec : ndarray, shape (M, w)
        Unit direction on those pixels (exact zeros dropped from the chord).
    response : ndarray, shape (M, N)
        ``A v``: the readings' change per unit step.
    lam : ndarray, shape (M,)
        ``|A v|^2`` (the eigenvalue of ``A_B^T A_B``, recomputed after zeroing).
    """

    index: np.ndarray
    vec: np.ndarray
    response: np.ndarray
    lam: np.ndarray

    @property
    def n_moves(self) -> int:
        """Number of moves M."""
        return int(self.lam.shape[0])


def window_moves(
    a: np.ndarray, groups: np.ndarray, sigma: float, *, slow: float = 5.0
) -> WindowMoves:
    """Slow eigen-directions of ``A_B^T A_B`` for every window ``B`` (row of groups).

    Parameters
    ----------
    a : ndarray, shape (N, K)
        Design matrix.
    groups : ndarray of int, shape (G, w)
        Windows of pixels (e.g. each pixel and its nearest neighbours);
        duplicate windows (same pixel set) are used once.
    sigma : float
        Noise sd.
    slow : float
        Keep a direction when its conditional sd ``sigma / sqrt(lambda)`` is at
        least ``slow`` times the largest single-site conditional sd
        ``sigma / |a_k|`` in the window -- the directions single-site moves
        cannot cross in a few steps.

    Returns
    -------
    WindowMoves
    """
    groups = np.unique(np.sort(np.asarray(groups, dtype=int), axis=1), axis=0)
    norm2 = np.einsum("nk,nk->k", a, a)
    idx, vecs = [], []
    for row in groups:
        ab = a[:, row]
        lam, v = np.linalg.eigh(ab.T @ ab)
        keep = lam * slow**2 <= norm2[row].min()
        for u in v[:, keep].T:
            u = np.where(np.abs(u) < _ZERO * np.abs(u).max(), 0.0, u)
            idx.append(row)
            vecs.append(u / np.linalg.norm(u))
    w = groups.shape[1]
    return line_moves(a, np.array(idx, dtype=int).reshape(-1, w),
                      np.array(vecs, dtype=float).reshape(-1, w))


def line_moves(a: np.ndarray, index: np.ndarray, vec: np.ndarray) -> WindowMoves:
    """Moves along given directions: ``vec[m]`` on pixels ``index[m]``, shapes (M, w)."""
    index = np.asarray(index, dtype=int)
    vec = np.asarray(vec, dtype=float)
    cols = np.ascontiguousarray(a.T)
    response = np.empty((index.shape[0], a.shape[0]))
    for m in range(index.shape[0]):  # one (w, N) gather at a time: no (M, w, N) temporary
        response[m] = vec[m] @ cols[index[m]]
    lam = np.einsum("mn,mn->m", response, response)
    return WindowMoves(index, vec, response, lam)


def coordinate_moves(a: np.ndarray, pairs: np.ndarray | None = None) -> WindowMoves:
    """Single-site moves along every ``e_k`` and pair moves along ``e_k - e_l``.

    The same exact moves as the numpy single-site / pair Gibbs of
    :mod:`olsbayes.imaging.sparse` (box prior), as :class:`WindowMoves` of
    width 2 (single sites padded with a zero component) for the compiled sweep.
    """
    k = a.shape[1]
    sites = np.column_stack([np.arange(k), np.arange(k)])
    svec = np.column_stack([np.ones(k), np.zeros(k)])
    pairs = np.zeros((0, 2), dtype=int) if pairs is None else np.asarray(pairs, dtype=int)
    pvec = np.tile([np.sqrt(0.5), -np.sqrt(0.5)], (pairs.shape[0], 1))
    return line_moves(a, np.vstack([sites, pairs]), np.vstack([svec, pvec]))


def combine(*moves: WindowMoves) -> WindowMoves:
    """One set of moves (directions padded with zeros to the widest window)."""
    w = max(m.index.shape[1] for m in moves)

    def pad(arr, fill):
        extra = w - arr.shape[1]
        return np.hstack([arr, np.repeat(fill, extra, axis=1)]) if extra else arr

    index = np.vstack([pad(m.index, m.index[:, :1]) for m in moves])
    vec = np.vstack([pad(m.vec, np.zeros((m.vec.shape[0], 1))) for m in moves])
    return WindowMoves(index, vec, np.vstack([m.response for m in moves]),
                       np.concatenate([m.lam for m in moves]))


def window_sweep(
    x: np.ndarray, r: np.ndarray, moves: WindowMoves, sigma: float, i_max: float,
    *, rng: np.random.Generator,
) -> None:
    """One exact Gibbs move along every window direction (random order), in place.

    Parameters
    ----------
    x : ndarray, shape (C, K)
        Intensities of C chains, inside [0, i_max] (C-contiguous float).
    r : ndarray, shape (C, N)
        Residuals ``y - A x`` (C-contiguous float; kept up to date).
    moves : WindowMoves
    sigma, i_max : float
    rng : Generator
        Draws the move order and one uniform per move and chain.
    """
    if moves.n_moves == 0:
        return
    from ._window_kernel import window_sweep_compiled  # numba is imported on first use

    order = rng.permutation(moves.n_moves)
    u = rng.random((moves.n_moves, x.shape[0]))
    window_sweep_compiled(x, r, order, moves.index, moves.vec, moves.response, moves.lam,
                          1.0 / sigma**2, float(i_max), u)
