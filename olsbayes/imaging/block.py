"""Exact HMC moves of the loose block of intensities, inside a Gibbs sweep.

Model ``y = A I + e``, ``e ~ N(0, sigma^2 1)``, flat prior on the box
``0 <= I <= i_max`` (``i_max`` may be inf).  On an ill-posed imaging design
most intensities are pinned -- by the data or against a wall of the box --
while a few dozen share a wide, nearly flat posterior: a polytope cut out of
the box by the design's (near-)null space.  Its slow directions are not local
(they join sources far apart on the sky), so single-site, pair and window
moves random-walk along them.

A block move samples the loose set ``L`` jointly given the rest: the
conditional of ``I_L`` is the truncated Gaussian

    p(I_L | I_rest) ∝ exp(-I_L^T Q_LL I_L / 2 + (b_L - Q_{L,rest} I_rest)^T I_L)

on the box, ``Q = A^T A / sigma^2``, ``b = A^T y / sigma^2``.  ``Q_LL`` is
singular where the block holds null-space patterns, so the move follows the
exact Hamiltonian dynamics of the surrogate with precision ``Q_LL + rho 1``
centred on ``c`` (:mod:`olsbayes.imaging.truncated`: no step size, exact wall
bounces) and accepts the end point with the Metropolis ratio of target to
surrogate, ``exp(rho (|I'_L - c|^2 - |I_L - c|^2) / 2)``.  The surrogate flow
is reversible and volume preserving, so each move leaves the conditional --
hence the posterior -- invariant.  Only the loose block's walls can be hit,
so a trajectory bounces a few hundred times instead of chattering against the
walls of every pinned intensity.

The block is chosen once from pilot draws (:func:`loose_block`) and then held
fixed, so the kept chain is a fixed, exact Markov kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .truncated import trajectory

__all__ = ["BlockMove", "block_move", "block_step", "compile_block_kernel", "loose_block"]


@dataclass(frozen=True)
class BlockMove:
    """A fixed block of intensities moved by exact HMC (``L`` of them).

    Attributes
    ----------
    index : ndarray of int, shape (L,)
        The block's intensities.
    cov : ndarray, shape (L, L)
        Covariance of the surrogate, ``(Q_LL + rho 1)^{-1}``.
    root : ndarray, shape (L, L)
        ``R`` with ``R^T R = cov``: surrogate velocities are ``z R``, z ~ N(0, 1).
    coupling : ndarray, shape (K, L)
        ``Q[:, L]``: how the other intensities shift the block's linear term.
    linear : ndarray, shape (L,)
        ``b_L + rho c``: the surrogate's linear term before the coupling.
    ridge : float
        ``rho`` (1 / intensity units^2).
    centre : float
        ``c``, the same for every intensity of the block (intensity units).
    """

    index: np.ndarray
    cov: np.ndarray
    root: np.ndarray
    coupling: np.ndarray
    linear: np.ndarray
    ridge: float
    centre: float

    @property
    def size(self) -> int:
        """Number of intensities L in the block."""
        return int(self.index.shape[0])


def loose_block(draws: np.ndarray, threshold: float) -> np.ndarray:
    """Intensities whose pooled pilot sd exceeds ``threshold``, shape (L,) of int.

    Parameters
    ----------
    draws : ndarray, shape (C, S, K)
        Pilot draws of C chains.
    threshold : float
        Intensity units.
    """
    flat = np.asarray(draws, dtype=float).reshape(-1, draws.shape[-1])
    return np.flatnonzero(flat.std(axis=0) > threshold)


def block_move(a: np.ndarray, y: np.ndarray, sigma: float, index: np.ndarray, scale: float
               ) -> BlockMove:
    """The block move of intensities ``index`` for design ``a`` (N, K) and readings ``y``.

    ``scale`` (intensity units) sets the surrogate: ridge ``1 / scale^2``, centre
    ``scale / 2`` -- the mean and about the spread of a uniform prior on
    ``[0, scale]``, so target and surrogate differ little on the box.
    """
    index = np.asarray(index, dtype=int)
    rho = 1.0 / scale**2
    a_l = a[:, index] / sigma
    q_ll = a_l.T @ a_l + rho * np.eye(index.shape[0])
    lq = np.linalg.cholesky(q_ll)
    root = np.linalg.solve(lq, np.eye(index.shape[0]))  # lq^{-1}: cov = root^T root
    coupling = a.T @ a_l / sigma
    linear = a_l.T @ y / sigma + rho * 0.5 * scale
    return BlockMove(index, root.T @ root, root, coupling, linear, rho, 0.5 * scale)


def block_step(x: np.ndarray, move: BlockMove, i_max: float, *, rng: np.random.Generator,
               max_bounces: int = 20_000, compiled: bool = True) -> tuple[int, int]:
    """One exact-HMC move of the block on every chain of ``x`` (C, K), in place.

    Returns (accepted, bounces) summed over the chains.  A trajectory that
    needs more than ``max_bounces`` bounces is rejected (a rule symmetric in
    time, so the move stays reversible).  ``compiled`` False follows the
    trajectories in numpy (:func:`olsbayes.imaging.truncated.trajectory`), the
    reference of the compiled kernel.
    """
    idx = move.index
    x_l = x[:, idx]
    rest = x.copy()
    rest[:, idx] = 0.0
    mu = (move.linear - rest @ move.coupling) @ move.cov  # (C, L): each chain's surrogate mean
    c = x.shape[0]
    v = rng.standard_normal((c, idx.shape[0])) @ move.root
    lower, upper = np.zeros(idx.shape[0]), np.full(idx.shape[0], i_max)
    if compiled:
        from ._block_kernel import trajectories_compiled  # numba is imported on first use

        new, bounces = trajectories_compiled(np.ascontiguousarray(x_l), mu, v, move.cov,
                                             lower, upper, np.pi / 2, max_bounces)
    else:
        new, bounces = trajectory(x_l, mu, v, move.cov, lower, upper, np.pi / 2, max_bounces)
    ok = np.all(np.isfinite(new), axis=1)
    new = np.where(ok[:, None], new, x_l)
    log_ratio = 0.5 * move.ridge * (np.sum((new - move.centre) ** 2, axis=1)
                                    - np.sum((x_l - move.centre) ** 2, axis=1))
    ok &= np.log(rng.random(c)) < log_ratio
    x[:, idx] = np.where(ok[:, None], np.clip(new, 0.0, i_max), x_l)
    return int(ok.sum()), int(bounces.sum())


def compile_block_kernel() -> None:
    """Compile (or load from numba's cache) the block moves' trajectory kernel."""
    from ._block_kernel import trajectories_compiled

    one = np.full((1, 1), 0.5)
    trajectories_compiled(one, one, one, np.ones((1, 1)), np.zeros(1), np.ones(1), 1.0, 10)
