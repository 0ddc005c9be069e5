"""Label switching: relabel exchangeable sources before any summary or plot.

The posterior of K exchangeable sources has K! symmetric copies.  Ordering by
the raw angle (theta_1 < theta_2) breaks on a circle: a source wandering over
+-pi jumps from first to last.  Here the labels are fixed in two steps:

1. a **reference**: the *anchor* when one is given -- the point the walkers
   started from, by default the maximum-likelihood estimate -- with its sources
   in the canonical order of :meth:`olsbayes.Model.canonical` (first location
   coordinate, angles wrapped to (-pi, pi]); without an anchor, the
   highest-posterior draw, its sources put in cyclic order from a pivot angle
   (the middle of the largest gap between all sampled source directions) or in
   (x, y, z) order for a plate;
2. **nearest-permutation relabelling** (Stephens 2000; Marin et al. 2005):
   every draw takes the permutation of its sources closest to the reference,
   the distance being a sum of squared standardised coordinate differences
   with *circular* differences for periodic coordinates; the reference is then
   replaced by the per-source means and scales and the step repeated.

Label j is then the posterior source matched to source j of the anchor, so a
posterior table, file or plot lists its sources exactly as the ML table does,
whatever the seed or the run length.  Without an anchor the final sources are
put in the canonical order of their (circular) means; only a source whose mean
sits at +-pi can then be listed first or last depending on the draws.

This works for any geometry because distances, not orderings, decide.
"""

from __future__ import annotations

import numpy as np

from ..circular import circular_mean, largest_gap_cut, wrap_angle
from ..exchange import best_permutation, pair_costs

__all__ = ["relabel", "reference_order", "canonical_order", "dominant_permutation",
           "block_index"]


def _diff(a: np.ndarray, b: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    d = a - b
    if periodic.any():  # wrap only the periodic columns (np.mod is the costly part)
        d[..., periodic] = wrap_angle(d[..., periodic])
    return d


#: Draws whose pair costs are built at once (temporaries small enough to stay in cache).
_CHUNK = 8192


def _nearest(blocks: np.ndarray, ref: np.ndarray, periodic: np.ndarray,
             scale: np.ndarray) -> np.ndarray:
    """Permutation (S, K) putting each draw's sources (S, K, w) nearest ``ref`` (K, w).

    Draw by draw the same costs and choice as
    ``best_permutation(pair_costs(blocks, ref, periodic, scale))``, in blocks of draws.
    """
    out = np.empty(blocks.shape[:2], dtype=np.int64)
    for lo in range(0, blocks.shape[0], _CHUNK):
        part = blocks[lo:lo + _CHUNK]
        out[lo:lo + part.shape[0]] = best_permutation(pair_costs(part, ref, periodic, scale))
    return out


def _permuted(blocks: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Blocks (S, K, w) with draw s's sources taken in the order ``perm[s]`` (S, K)."""
    return blocks[np.arange(blocks.shape[0])[:, None], perm]


def reference_order(blocks: np.ndarray, periodic: np.ndarray, pivot: float) -> np.ndarray:
    """Permutation putting one draw's sources (K, w) in canonical order.

    Periodic first coordinate: cyclic order of ``(angle - pivot) mod 2 pi``;
    otherwise lexicographic order of the location coordinates.
    """
    if periodic[0]:
        return np.argsort(np.mod(blocks[:, 0] - pivot, 2 * np.pi), kind="stable")
    return np.lexsort(blocks[:, :-1].T[::-1])


def canonical_order(blocks: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Permutation (K,) putting sources (K, w) in the order of :meth:`Model.canonical`.

    Sorted by the first location coordinate, wrapped to (-pi, pi] when periodic
    (a stable sort: ties keep their order).
    """
    key = wrap_angle(blocks[:, 0]) if periodic[0] else blocks[:, 0]
    return np.argsort(key, kind="stable")


def _mean_scale(blocks: np.ndarray, periodic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-source (circular) means and sds, each (K, w), of blocks (S, K, w)."""
    mean = blocks.mean(axis=0)
    if periodic.any():
        mean[:, periodic] = circular_mean(blocks[:, :, periodic], axis=0)
    dev = _diff(blocks, mean, periodic)
    scale = np.sqrt(np.mean(dev * dev, axis=0))
    return mean, scale


def relabel(
    samples: np.ndarray,
    n_sources: int,
    periodic_loc: np.ndarray,
    log_post: np.ndarray | None = None,
    n_iter: int = 3,
    *,
    anchor: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Relabel draws of K exchangeable sources.

    Parameters
    ----------
    samples : ndarray (..., P)
        Draws in the model's flat layout; a trailing non-source parameter
        (``sigma``) is allowed and left in place.
    n_sources : int
    periodic_loc : ndarray of bool (w,)
        Which of a source's w = d + 1 coordinates are periodic.
    log_post : ndarray (...,), optional
        Log posterior of each draw; its argmax is the reference draw.
    n_iter : int
        Most reference-update iterations (fewer when the labels stop changing: the
        same labels give the same reference, so the rest would repeat them).
    anchor : ndarray (P,) or (K (d + 1),), optional
        A point in the flat layout (the walkers' starting point, the ML estimate
        by default); its sources, in canonical order, are the first reference
        and fix the final labels.  None: the highest-posterior draw, and the
        final sources in canonical order of their means.

    Returns
    -------
    relabelled : ndarray (..., P)
    perms : ndarray of int (..., K)
        ``relabelled source j = original source perms[..., j]``.
    """
    x = np.asarray(samples, dtype=float)
    k, w = int(n_sources), len(periodic_loc)
    lead = x.shape[:-1]
    flat = x.reshape(-1, x.shape[-1])
    ident = np.broadcast_to(np.arange(k), lead + (k,)).copy()
    if k <= 1 or flat.shape[0] == 0:
        return x.copy(), ident
    blocks = flat[:, : k * w].reshape(-1, k, w)
    periodic = np.asarray(periodic_loc, dtype=bool)
    if anchor is not None:
        ref = np.asarray(anchor, dtype=float)[: k * w].reshape(k, w)
        ref = ref[canonical_order(ref, periodic)]
    else:
        pivot = largest_gap_cut(blocks[:, :, 0]) if periodic[0] else 0.0
        best = 0 if log_post is None else int(np.nanargmax(np.ravel(log_post)))
        ref = blocks[best][reference_order(blocks[best], periodic, pivot)]
    _, scale = _mean_scale(blocks, periodic)
    scale = np.broadcast_to(np.maximum(scale.mean(axis=0), 1e-300), (k, w))
    perm = None
    for _ in range(max(1, n_iter)):
        last, perm = perm, _nearest(blocks, ref, periodic, scale)
        if last is not None and np.array_equal(perm, last):
            break  # the same labels give the same reference: a fixed point
        ordered = _permuted(blocks, perm)
        ref, scale = _mean_scale(ordered, periodic)
        scale = np.maximum(scale, 1e-12 * np.maximum(scale.max(axis=0), 1e-300))
    if anchor is None:  # labels follow the anchor's sources when there is one
        perm = perm[:, canonical_order(ref, periodic)]
    out = flat.copy()
    out[:, : k * w] = _permuted(blocks, perm).reshape(-1, k * w)
    return out.reshape(x.shape), perm.reshape(lead + (k,))


def dominant_permutation(perms: np.ndarray) -> tuple[np.ndarray, float]:
    """The most common permutation (K,) of :func:`relabel`'s ``perms`` (..., K).

    Also the fraction of draws that use another one (the label-switch fraction).
    """
    flat = perms.reshape(-1, perms.shape[-1])
    if flat.shape[0] == 0:
        return np.arange(perms.shape[-1]), 0.0
    k = flat.shape[1]
    if k ** k < 2**62:  # each permutation as one integer, in lexicographic order
        digits = np.asarray(flat, dtype=np.int64) @ (k ** np.arange(k - 1, -1, -1, dtype=np.int64))
        codes, first, counts = np.unique(digits, return_index=True, return_counts=True)
        best = int(np.argmax(counts))  # ties: the lexicographically first, as below
        return flat[first[best]].copy(), float(1.0 - counts[best] / flat.shape[0])
    uniq, counts = np.unique(flat, axis=0, return_counts=True)
    best = int(np.argmax(counts))
    return uniq[best], float(1.0 - counts[best] / flat.shape[0])


def block_index(perm: np.ndarray, w: int, n_params: int) -> np.ndarray:
    """Flat index (P,) taking parameters from source ``perm[j]`` into label j's block.

    Each block has w coordinates; trailing non-source parameters (``sigma``) stay in place.
    """
    k = len(perm)
    idx = np.arange(n_params)
    idx[: k * w] = (np.asarray(perm)[:, None] * w + np.arange(w)).ravel()
    return idx
