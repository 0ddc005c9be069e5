"""Nearest imaged sources: the pairs and windows of the local moves.

Distance between two sources is Euclidean for near-source positions and
``1 - cos`` of the angle between their unit vectors for ring and sphere
directions; ties are broken by source index.
"""

from __future__ import annotations

import numpy as np

from ..geometry import lonlat_to_unit
from ..model import Model

__all__ = ["neighbour_pairs", "neighbour_groups"]


def neighbour_pairs(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Unique pairs (k, l), shape (P, 2), of each source with its n nearest sources.

    ``loc`` has shape (K, d) (validated locations for ``model``).
    """
    k = loc.shape[0]
    n = min(n, k - 1)
    if n <= 0:
        return np.zeros((0, 2), dtype=int)
    near = _nearest(model, loc, n)
    pairs = np.sort(np.column_stack([np.repeat(np.arange(k), n), near.ravel()]), axis=1)
    return np.unique(pairs, axis=0)


def neighbour_groups(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Each source with its n nearest sources, shape (K, min(n, K - 1) + 1)."""
    n = min(n, loc.shape[0] - 1)
    return np.column_stack([np.arange(loc.shape[0]), _nearest(model, loc, n)])


def _nearest(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Indices, shape (K, n), of each source's n nearest other sources."""
    if model.kind == "position":
        d2 = np.sum((loc[:, None, :] - loc[None, :, :]) ** 2, axis=-1)
    else:  # angular distance through unit vectors (1 - cos)
        if model.kind == "angle":
            v = np.column_stack([np.cos(loc[:, 0]), np.sin(loc[:, 0])])
        else:
            v = lonlat_to_unit(loc[:, 0], loc[:, 1])
        d2 = 1.0 - v @ v.T
    np.fill_diagonal(d2, np.inf)
    return np.argsort(d2, axis=1, kind="stable")[:, :n]
