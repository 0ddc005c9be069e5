"""Eq. 1 for sources near a plate: the gain g(c) / r^2 and its Jacobian.

A source at position p seen by a sub-sensor at q with unit normal n has
``d = p - q``, ``r = |d|``, ``c = n . d / r`` and contributes ``I g(c) / r^2``.
The far-field kernels live in :mod:`olsbayes.model`; these two serve its
``"position"`` sources.
"""

from __future__ import annotations

import numpy as np

from .sensitivity import Sensitivity

__all__ = ["near_gain", "near_jacobian_t"]


def near_gain(where: np.ndarray, positions_t: np.ndarray, normals_t: np.ndarray,
              law: Sensitivity) -> np.ndarray:
    """g(c) / r^2 of sources at ``where`` (B, K, 3) for N sub-sensors: shape (B, K, N).

    ``positions_t`` and ``normals_t`` (3, N) are the sub-sensors' positions and
    normals, transposed.  Computed component by component: exact, and no
    (B, K, N, 3) intermediate.
    """
    r2, nd = None, None
    for i in range(3):
        di = where[:, :, i, None] - positions_t[i]
        ndi = di * normals_t[i]
        nd = ndi if nd is None else np.add(nd, ndi, out=nd)
        np.multiply(di, di, out=di)
        r2 = di if r2 is None else np.add(r2, di, out=r2)
    c = np.divide(nd, np.sqrt(r2), out=nd)
    return np.divide(law.value(c), r2, out=r2)


def near_jacobian_t(loc: np.ndarray, inten: np.ndarray, positions: np.ndarray,
                    normals: np.ndarray, law: Sensitivity) -> np.ndarray:
    """d (I g(c) / r^2) / d (position, I) of sources ``loc`` (..., K, 3): (..., K, 4, N).

    ``inten`` (..., K) are the intensities; ``positions`` and ``normals`` (N, 3)
    the sub-sensors'.
    """
    d = loc[..., :, None, :] - positions  # (..., K, N, 3)
    r2 = np.einsum("...i,...i->...", d, d)
    r = np.sqrt(r2)
    c = np.einsum("...ni,ni->...n", d, normals) / r
    g, dg = law.value(c), law.derivative(c)
    dc = normals / r[..., None] - (c / r2)[..., None] * d  # (..., K, N, 3)
    dpos = (dg / r2)[..., None] * dc - (2.0 * g / r2**2)[..., None] * d
    d_loc = np.moveaxis(inten[..., None, None] * dpos, -1, -2)  # (..., K, 3, N)
    return np.concatenate([d_loc, (g / r2)[..., None, :]], axis=-2)
