"""Exchangeable sources: one rule for matching the sources of two parameter sets.

The likelihood of K sources is symmetric under permutations of the sources, so
comparing an estimate with a truth, a posterior draw with a reference, or a
rival optimum with an ML fit first needs the permutation that puts each source
against its counterpart.  Sorting by angle does not do it (a weak source wanders
past a strong one; a source crosses +-pi), so every caller uses the same rule:

    the permutation pi minimising  sum_j sum_c ((a[pi(j), c] - b[j, c]) / s[j, c])^2

over the compared coordinates c, with circular differences (wrapped to (-pi, pi])
for periodic coordinates and optional scales s.  Exhaustive over the K!
permutations up to :data:`MAX_EXHAUSTIVE` sources (ties go to the first
permutation in lexicographic order), the Hungarian algorithm
(:func:`scipy.optimize.linear_sum_assignment`) beyond.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

from .circular import wrap_angle
from .errors import InputError

__all__ = ["MAX_EXHAUSTIVE", "permutations", "pair_costs", "best_permutation",
           "match_sources", "estimation_errors"]

#: Largest K whose permutations are searched exhaustively.
MAX_EXHAUSTIVE = 7


@lru_cache(maxsize=None)
def _permutations(k: int) -> np.ndarray:
    out = np.array(list(itertools.permutations(range(k))), dtype=np.int64).reshape(-1, k)
    out.flags.writeable = False
    return out


def permutations(k: int) -> np.ndarray:
    """All K! permutations of range(K) in lexicographic order, shape (K!, K), read-only."""
    return _permutations(int(k))


def pair_costs(a: np.ndarray, b: np.ndarray, periodic: np.ndarray,
               scale: np.ndarray | None = None) -> np.ndarray:
    """Squared distances between every source of ``a`` and every source of ``b``.

    Parameters
    ----------
    a, b : ndarray, shape (..., K, c)
        The compared coordinates of K sources each (leading axes broadcast).
    periodic : ndarray of bool, shape (c,)
        Coordinates compared circularly (angles, rad).
    scale : ndarray, shape (K, c), optional
        Per-source scales of ``b``'s coordinates; differences are divided by them.

    Returns
    -------
    ndarray, shape (..., K, K)
        ``cost[..., i, j]``: source i of ``a`` against source j of ``b``.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    periodic = np.asarray(periodic, dtype=bool)
    out = None
    for c in range(a.shape[-1]):  # one coordinate at a time: no (..., K, K, c) temporaries
        d = a[..., :, None, c] - b[..., None, :, c]
        if periodic[c]:
            d = wrap_angle(d)
        if scale is not None:
            d = d / scale[..., None, :, c]
        d *= d
        out = d if out is None else out + d  # summed in coordinate order, as np.sum does
    return out


def best_permutation(cost: np.ndarray) -> np.ndarray:
    """The assignment minimising the summed cost, per leading index.

    Parameters
    ----------
    cost : ndarray, shape (..., K, K)
        :func:`pair_costs`: ``cost[..., i, j]`` of giving label j to source i.

    Returns
    -------
    ndarray of int, shape (..., K)
        ``perm[..., j]``: the source that takes label j.
    """
    k = cost.shape[-1]
    lead = cost.shape[:-2]
    if k <= 2:
        perms = permutations(k)
        total = cost[..., perms, np.arange(k)].sum(axis=-1)  # (..., K!)
        return perms[np.argmin(total, axis=-1)]
    if k <= MAX_EXHAUSTIVE:
        return _exhaustive(cost.reshape(-1, k * k), k).reshape(lead + (k,))
    from scipy.optimize import linear_sum_assignment

    flat = cost.reshape(-1, k, k)
    out = np.empty((flat.shape[0], k), dtype=np.int64)
    for s in range(flat.shape[0]):  # one assignment problem per draw
        rows, cols = linear_sum_assignment(flat[s])
        out[s, cols] = rows
    return out.reshape(lead + (k,))


#: Elements of the (K!, draws) table of permutation totals built at once by :func:`_exhaustive`.
_TOTALS_CHUNK = 1 << 22


def _exhaustive(flat: np.ndarray, k: int) -> np.ndarray:
    """Best permutation (S, K) of each row of ``flat`` (S, K * K), over all K! of them.

    The totals are summed label by label, ``((c_0 + c_1) + c_2) + ...`` as ``np.sum`` over
    a short axis does, on cost columns laid out as contiguous rows, in blocks of draws
    that keep the (K!, block) table of totals small.
    """
    perms = permutations(k)
    cols = perms * k + np.arange(k)  # (K!, K): flat index of cost[perm[j], j]
    out = np.empty((flat.shape[0], k), dtype=np.int64)
    step = max(1, _TOTALS_CHUNK // len(perms))
    for lo in range(0, flat.shape[0], step):
        rows = np.ascontiguousarray(flat[lo:lo + step].T)  # (K * K, block)
        total = rows[cols[:, 0]] + rows[cols[:, 1]]
        for j in range(2, k):
            total += rows[cols[:, j]]
        out[lo:lo + step] = perms[np.argmin(total, axis=0)]
    return out


def _blocks(model, x: np.ndarray, k: int) -> np.ndarray:
    return x.reshape(x.shape[:-1] + (k, model.n_loc + 1))


def _periodic(model) -> np.ndarray:
    """Which location coordinates of the model's sources are angles (compared circularly)."""
    out = np.zeros(model.n_loc, dtype=bool)
    out[0] = model.kind != "position"
    return out


def match_sources(model, est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``est`` with its sources permuted to best match ``truth`` by location.

    Parameters
    ----------
    model : Model
    est : ndarray, shape (..., P)
        Parameters in the model's flat layout.
    truth : ndarray, shape (P,) or (..., P)
        Reference parameters (leading axes broadcast against ``est``'s).

    Returns
    -------
    ndarray, shape of ``est`` broadcast against ``truth``
        The matched estimates (locations and intensities move together).
    """
    est, tru = np.asarray(est, dtype=float), np.asarray(truth, dtype=float)
    k = model.n_sources_of(tru)
    if est.shape[-1] != tru.shape[-1]:
        raise InputError(f"params must have last axis {tru.shape[-1]} like truth; got shapes "
                         f"{est.shape} and {tru.shape}")
    e, t = _blocks(model, est, k), _blocks(model, tru, k)
    shape = np.broadcast_shapes(e.shape, t.shape)
    e = np.broadcast_to(e, shape)
    perm = best_permutation(pair_costs(e[..., :-1], t[..., :-1], _periodic(model)))
    return np.take_along_axis(e, perm[..., None], axis=-2).reshape(shape[:-2] + (-1,))


def estimation_errors(model, params: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Errors ``params - truth`` after matching estimated to true sources.

    Sources are exchangeable, so each estimate's sources are first permuted to
    the assignment minimising the summed squared location error
    (:func:`match_sources`).

    Parameters
    ----------
    model : Model
    params : ndarray, shape (..., P)
        Estimates in the model's flat layout.
    truth : ndarray, shape (P,) or (..., P)
        One truth, or one per estimate (leading axes broadcast against params').

    Returns
    -------
    ndarray, shape (..., P)
        Errors in the layout (and source order) of ``truth``; angle errors wrapped
        to (-pi, pi].
    """
    tru = np.asarray(truth, dtype=float)
    matched = match_sources(model, params, tru)
    k = model.n_sources_of(tru)
    err = _blocks(model, matched, k) - _blocks(model, tru, k)
    if model.kind != "position":
        err[..., 0] = wrap_angle(err[..., 0])
    return err.reshape(matched.shape)
