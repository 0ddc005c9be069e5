"""MAP search for the two-level prior: every intensity is 0 (dark) or i_max (bright).

Model ``y = A I + e``, ``e ~ N(0, sigma^2 1)``, with independent priors
``P(I_k = i_max) = p`` and ``P(I_k = 0) = 1 - p``.  The log posterior of a
binary scene ``I = i_max * s`` (``s`` in {0, 1}^K) is, up to a constant,

    L(s) = -|y - A I|^2 / (2 sigma^2) + n_bright log p + (K - n_bright) log(1 - p),

and its maximiser is a binary quadratic program (NP-hard in general).
:func:`two_level_map` is a heuristic: from a starting scene rounded to
{0, i_max} it makes the best improving move -- a single flip, any 2-flip (or
only the bright/dark swaps of given pairs), or a flip of up to 4 sources of a
small group of neighbours (the 2 x 2 checkerboards that a sphere with
antipodal sub-sensors barely sees) -- until none improves L.  Gains come from
``c = A^T r`` and ``G = A^T A``; a move updates ``c`` by rank-1 corrections,
O(K) per flipped source.  :func:`olsbayes.imaging.image` runs it from two
starts, the rounded bounded least-squares mode and the rounded sparse (L1)
relaxation :func:`sparse_relaxation`, and keeps the better local optimum.

The result is a local optimum under these moves, not a certified global one:
:class:`BinaryMap` says how the search ended and, when a reference scene is
given, whether that scene has a higher L (a search failure).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .._store import storable
from ..errors import ConvergenceWarning

__all__ = ["BinaryMap", "sparse_relaxation", "two_level_log_posterior", "two_level_map"]


@storable
@dataclass(frozen=True)
class BinaryMap:
    """Outcome of the two-level MAP search.

    Attributes
    ----------
    x : ndarray, shape (K,)
        The scene found, each intensity 0 or i_max.
    log_posterior : float
        L(x) (natural log, additive constant dropped; see the module notes).
    start_log_posterior : float
        L of the rounded starting scene.
    n_flips, n_swaps, n_group_moves : int
        Moves made of each kind (single flips, 2-flips, group flips of 3 or more).
    local_optimum : bool
        True when the search stopped because no flip or pair swap improves L;
        False when it hit ``max_moves``.
    reference_log_posterior : float or None
        L of a reference scene (e.g. the truth in a simulation) when one was given.
    """

    x: np.ndarray
    log_posterior: float
    start_log_posterior: float
    n_flips: int
    n_swaps: int
    n_group_moves: int
    local_optimum: bool
    reference_log_posterior: float | None = None

    @property
    def reference_better(self) -> bool | None:
        """True when the reference scene has a higher L: the search failed to find it."""
        if self.reference_log_posterior is None:
            return None
        tol = 1e-9 * max(1.0, abs(self.log_posterior))
        return bool(self.reference_log_posterior > self.log_posterior + tol)


def sparse_relaxation(
    a: np.ndarray, y: np.ndarray, sigma: float, i_max: float, weight: float = 0.3
) -> np.ndarray:
    """A sparse starting scene: ``min weight * sum(I) / i_max + sum(|A I - y|) / sigma``.

    A linear program on ``0 <= I <= i_max`` (HiGHS): the L1 relaxation of "few
    bright sources that fit the readings".  Where the design has a large null
    space, bounded least squares picks an arbitrary point of the set of
    equally good fits and its rounding can be many flips from any good binary
    scene; the L1 term picks a sparse one instead.  Returns shape (K,); all
    zeros, with a ConvergenceWarning, if HiGHS fails.
    """
    from scipy.optimize import linprog  # on use: scipy is slow to import
    n, k = a.shape
    cost = np.concatenate([np.full(k, weight / i_max), np.full(2 * n, 1.0 / sigma)])
    a_eq = np.hstack([a, -np.eye(n), np.eye(n)])  # A I - e_plus + e_minus = y
    bounds = [(0.0, i_max)] * k + [(0.0, None)] * (2 * n)
    lp = linprog(cost, A_eq=a_eq, b_eq=y, bounds=bounds, method="highs")
    if lp.status != 0 or lp.x is None:
        warnings.warn(f"sparse relaxation failed ({lp.message}); starting from all dark",
                      ConvergenceWarning, stacklevel=2)
        return np.zeros(k)
    return np.clip(lp.x[:k], 0.0, i_max)


def two_level_log_posterior(
    a: np.ndarray, y: np.ndarray, sigma: float, x: np.ndarray, i_max: float, p_bright: float
) -> float:
    """L(x) for a scene ``x`` with entries 0 or i_max (a bright entry is ``x > i_max / 2``)."""
    on = np.asarray(x) > 0.5 * i_max
    xs = np.where(on, i_max, 0.0)
    r = y - a @ xs
    n_on = int(on.sum())
    return float(-0.5 * (r @ r) / sigma**2 + n_on * np.log(p_bright)
                 + (on.size - n_on) * np.log1p(-p_bright))


def two_level_map(
    a: np.ndarray,
    y: np.ndarray,
    sigma: float,
    i_max: float,
    start: np.ndarray,
    *,
    p_bright: float = 0.5,
    pairs: np.ndarray | str | None = "all",
    groups: np.ndarray | None = None,
    max_group_flips: int = 4,
    reference: np.ndarray | None = None,
    max_moves: int | None = None,
) -> BinaryMap:
    """Best-improvement local search for the two-level MAP.

    Parameters
    ----------
    a : ndarray, shape (N, K)
        Design matrix.
    y : ndarray, shape (N,)
    sigma : float
        Noise sd of one reading.
    i_max : float
        Intensity of a bright source (> 0).
    start : ndarray, shape (K,)
        Starting intensities; rounded to the nearer of 0 and i_max.
    p_bright : float in (0, 1)
        Prior probability that a source is bright.
    pairs : "all", ndarray of int, shape (P, 2), or None
        ``"all"``: every 2-flip is a move (a K x K gain table per move); an
        array: only the bright/dark swaps of these pairs; None: single flips only.
    groups : ndarray of int, shape (G, m), optional
        Small groups of sources (e.g. each source with its nearest neighbours):
        flipping any subset of up to ``max_group_flips`` sources of a group is
        a move -- e.g. the 2 x 2 checkerboards a sphere with antipodal
        sub-sensors barely sees.
    reference : ndarray, shape (K,), optional
        A scene to compare with (rounded like ``start``): its L is reported.
    max_moves : int, optional
        Stop after this many moves (default 10 K).
    """
    k = a.shape[1]
    s = np.asarray(start, dtype=float) > 0.5 * i_max
    all_pairs = isinstance(pairs, str) and pairs == "all"
    no_list = pairs is None or all_pairs
    pairs = np.zeros((0, 2), dtype=int) if no_list else np.asarray(pairs, dtype=int)
    pk, pl = pairs[:, 0], pairs[:, 1]
    g = a.T @ a
    gd = np.diag(g).copy()
    pair_q = gd[pk] + gd[pl] - 2.0 * g[pk, pl]  # |a_k - a_l|^2
    c = a.T @ (y - a @ np.where(s, i_max, 0.0))
    prior_gain = np.log(p_bright) - np.log1p(-p_bright)  # of a dark -> bright flip
    lp0 = two_level_log_posterior(a, y, sigma, s, i_max, p_bright)
    max_moves = 10 * k if max_moves is None else max_moves
    if groups is not None:
        groups = np.asarray(groups, dtype=int)
        masks = _subset_masks(groups.shape[1], max_group_flips)
    n_flips = n_swaps = n_group = 0
    inv2s2 = 0.5 / sigma**2
    local = False
    while n_flips + n_swaps + n_group < max_moves:
        d = np.where(s, -i_max, i_max)  # change of each intensity if flipped
        flip = (2.0 * d * c - d**2 * gd) * inv2s2 + np.where(s, -prior_gain, prior_gain)
        j = int(np.argmax(flip))
        best, move = flip[j], (j,)
        gain, pair = _best_pair(flip, d, c, s, g, all_pairs, pairs, pair_q, inv2s2)
        if gain > best:
            best, move = gain, pair
        if groups is not None:
            gain, sub = _group_gains(flip, d, g, groups, masks, inv2s2)
            if gain > best:
                best, move = gain, sub
        if not best > 1e-12 * max(1.0, abs(lp0)):
            local = True
            break
        for m in move:
            c -= d[m] * g[:, m]
            s[m] = ~s[m]
        n_flips += len(move) == 1
        n_swaps += len(move) == 2
        n_group += len(move) > 2
    x = np.where(s, i_max, 0.0)
    ref = None
    if reference is not None:
        ref = two_level_log_posterior(a, y, sigma, reference, i_max, p_bright)
    return BinaryMap(
        x=x, log_posterior=two_level_log_posterior(a, y, sigma, x, i_max, p_bright),
        start_log_posterior=lp0, n_flips=int(n_flips), n_swaps=int(n_swaps),
        n_group_moves=int(n_group),
        local_optimum=local, reference_log_posterior=ref,
    )


def _best_pair(flip, d, c, s, g, all_pairs, pairs, pair_q, inv2s2):
    """Best 2-flip gain and its two sources; (-inf, ()) when there is no pair move.

    ``all_pairs``: any 2-flip, gain ``F_k + F_l - d_k d_l G_kl / sigma^2``;
    else the bright/dark swaps of the listed ``pairs`` (shape (P, 2), with
    ``pair_q = |a_k - a_l|^2``).
    """
    if all_pairs:
        two = flip[:, None] + flip[None, :] - np.outer(d, d) * g * (2.0 * inv2s2)
        np.fill_diagonal(two, -np.inf)
        p = int(np.argmax(two))
        return two.flat[p], divmod(p, flip.shape[0])
    if not pairs.shape[0]:
        return -np.inf, ()
    pk, pl = pairs[:, 0], pairs[:, 1]
    ok = s[pk] != s[pl]
    dk = d[pk]
    swap = np.where(ok, (2.0 * dk * (c[pk] - c[pl]) - dk**2 * pair_q) * inv2s2, -np.inf)
    p = int(np.argmax(swap))
    return swap[p], (int(pk[p]), int(pl[p]))


def _subset_masks(m: int, max_flips: int) -> np.ndarray:
    """0/1 masks, shape (S, m), of the subsets of m items with 3 .. max_flips members."""
    bits = (np.arange(2**m)[:, None] >> np.arange(m)) & 1
    size = bits.sum(axis=1)
    return bits[(size >= 3) & (size <= max_flips)].astype(float)


def _group_gains(flip, d, g, groups, masks, inv2s2):
    """Best gain over flips of subsets of each group, and its source indices.

    gain(S) = sum_{i in S} F_i - sum_{i < j in S} d_i d_j G_ij / sigma^2, for all
    groups and masks at once: one (G, m) x (m, S) and one (G, m^2) x (m^2, S) product.
    """
    if masks.shape[0] == 0:
        return -np.inf, ()
    m = groups.shape[1]
    dg = d[groups]
    cross = -(dg[:, :, None] * dg[:, None, :]) * g[groups[:, :, None], groups[:, None, :]]
    cross *= inv2s2  # = -d_i d_j G_ij / (2 sigma^2); each unordered pair counted twice below
    idx = np.arange(m)
    cross[:, idx, idx] = 0.0
    pair_masks = (masks[:, :, None] * masks[:, None, :]).reshape(masks.shape[0], m * m)
    gains = flip[groups] @ masks.T + cross.reshape(groups.shape[0], m * m) @ pair_masks.T
    j = int(np.argmax(gains))
    gi, si = divmod(j, masks.shape[0])
    return float(gains.flat[j]), tuple(int(v) for v in groups[gi, masks[si] > 0])
