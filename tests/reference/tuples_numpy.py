"""Numpy reference of the K-tuple scan (:mod:`olsbayes.ml._numba.tuples`).

The same block elimination, in the plan's float type, with the compiled kernel's
order of operations (same rounding) and tie-breaking (first maximum): the tests
check that both pick the same tuples.
"""

from __future__ import annotations

import numpy as np

from olsbayes.ml.fast.tuples import TuplePlan

__all__ = ["tuple_scores", "tuple_search"]

_BLOCK = 32_768  # elements of each (t, C) work array per block


def tuple_scores(plan: TuplePlan, corr: np.ndarray) -> np.ndarray:
    """RSS drop of every tuple, -inf where an intensity is negative: shape (t, C).

    ``corr`` (t, Mc): data . coarse atoms, rounded to the plan's float type.  The
    block elimination of the module docstring, in that type, with the compiled
    kernel's order of operations (same rounding).
    """
    corr = np.asarray(corr).astype(plan.ext.dtype, copy=False)
    km = plan.prefixes.shape[0]
    owner = np.repeat(np.arange(plan.prefixes.shape[1]), np.diff(plan.ext_ptr))
    bp = [corr[:, plan.prefixes[i]] for i in range(km)]  # K - 1 arrays (t, R)
    f = []
    for i in range(km):
        fi = plan.prefix_inv[i, 0] * bp[0]
        for j in range(1, km):
            fi = fi + plan.prefix_inv[i, j] * bp[j]
        f.append(fi)
    sp = bp[0] * f[0]
    for i in range(1, km):
        sp = sp + bp[i] * f[i]
    w, inv_schur = plan.ext[:km], plan.ext[km]  # (ext[km + 1]: the tuple numbers)
    acc = w[0] * bp[0][:, owner]
    for i in range(1, km):
        acc = acc + w[i] * bp[i][:, owner]
    r = corr[:, plan.columns[km]] - acc
    cd = r * inv_schur
    score = sp[:, owner] + r * cd
    feasible = cd >= 0.0
    for i in range(km):
        feasible &= f[i][:, owner] - w[i] * cd >= 0.0
    return np.where(feasible, score, -np.inf)


def tuple_search(
    plan: TuplePlan, data: np.ndarray, distinct: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Best feasible K-tuple of the plan's coarse atoms for every data vector (numpy).

    Parameters
    ----------
    plan : TuplePlan
    data : ndarray, shape (T, N)
    distinct : bool
        Also return the best feasible tuple none of whose atoms is in the basin
        (``plan.near``) of an atom of the best one: a second, distinct mode (the
        best tuple again where there is none).

    Returns
    -------
    ndarray of int, shape (T, K)
        Fine-grid indices of the tuple with the largest drop in residual sum of
        squares among tuples whose least-squares intensities are all >= 0; with
        ``distinct``, a pair (best, second mode).
    """
    n_c = plan.combos.shape[0]
    corr = data @ plan.atoms.T  # (T, Mc)
    step = max(1, _BLOCK // max(n_c, 1))
    best = np.empty(data.shape[0], dtype=np.int64)
    second = best.copy()
    for start in range(0, data.shape[0], step):
        sc = tuple_scores(plan, corr[start : start + step])
        top = np.argmax(sc, axis=1)
        best[start : start + step] = top
        if distinct:
            blocked = plan.near[plan.combos[top]].any(axis=1)  # (t, Mc)
            sc[blocked[:, plan.combos].any(axis=2)] = -np.inf  # a blocked atom
            alt = np.argmax(sc, axis=1)
            none = ~np.isfinite(sc[np.arange(sc.shape[0]), alt])
            second[start : start + step] = np.where(none, top, alt)
    if distinct:
        return plan.subset[plan.combos[best]], plan.subset[plan.combos[second]]
    return plan.subset[plan.combos[best]]
