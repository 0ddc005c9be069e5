"""The imaging design matrix: Eq. 1 with the source directions held fixed.

With K sources at known directions (or near-source positions), Eq. 1 reads
``s = A I + noise`` where ``A[n, k] = g(n_n . u_k)`` (divided by ``r^2`` for near
sources) is the reading of sub-sensor n for a unit-intensity source k.  The
model is linear in the intensities ``I``; everything the array can and cannot
tell about them is in the singular values of ``A``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._store import storable
from .._validation import finite_array
from ..errors import InputError
from ..model import Model

__all__ = ["Design", "check_directions", "design_matrix", "analyse_design"]


def check_directions(model: Model, directions: object) -> np.ndarray:
    """Validate source locations for ``model``'s array; return shape (K, d).

    Parameters
    ----------
    model : Model
        The forward model (its ``kind`` fixes the location format).
    directions : array_like
        Ring: angles in rad, shape (K,) or (K, 1).  Sphere: (longitude,
        latitude) pairs in rad, shape (K, 2), latitude in [-pi/2, pi/2].
        Plate: positions, shape (K, 3), with z > 0.

    Raises
    ------
    InputError
        Empty grid, wrong shape, non-finite values or a location outside the
        source space of the array.
    """
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    d = model.n_loc
    arr = finite_array("directions", directions, ndim=(1, 2), allow_empty=True)
    if arr.size == 0:
        raise InputError(f"directions must hold at least one source; got shape {arr.shape}")
    if arr.ndim == 1:
        if d != 1:
            raise InputError(
                f"directions must have shape (K, {d}) for a {model.kind!r} array; "
                f"got shape {arr.shape}"
            )
        arr = arr[:, None]
    if arr.shape[1] != d:
        raise InputError(
            f"directions must have shape (K, {d}) for a {model.kind!r} array; got shape {arr.shape}"
        )
    if model.kind == "lonlat":
        bad = np.abs(arr[:, 1]) > np.pi / 2 + 1e-12
        if np.any(bad):
            raise InputError(
                "directions latitude must be in [-pi/2, pi/2] rad; got "
                f"{float(arr[bad, 1][0])!r} (source {int(np.flatnonzero(bad)[0])})"
            )
        arr = np.column_stack([arr[:, 0], np.clip(arr[:, 1], -np.pi / 2, np.pi / 2)])
    if model.kind == "position" and np.any(arr[:, 2] <= 0):
        k = int(np.flatnonzero(arr[:, 2] <= 0)[0])
        raise InputError(
            f"directions (positions) must have z > 0 (in front of the plate); got z = "
            f"{float(arr[k, 2])!r} for source {k}"
        )
    return arr


def design_matrix(model: Model, directions: object) -> np.ndarray:
    """Readings of every sub-sensor for a unit source at each location.

    Returns
    -------
    ndarray, shape (N, K)
        ``A[n, k]``: noiseless reading of sub-sensor n for source k of intensity 1.
        Columns that are all zero (a source no sub-sensor sees) raise InputError.
    """
    loc = check_directions(model, directions)
    k = loc.shape[0]
    params = np.column_stack([loc, np.ones(k)])  # batch of K one-source scenes
    a = np.ascontiguousarray(model.response(params).T)
    dark = ~np.any(a > 0, axis=0)
    if np.any(dark):
        j = int(np.flatnonzero(dark)[0])
        raise InputError(
            f"directions[{j}] = {loc[j].tolist()} is seen by no sub-sensor (outside the "
            f"array's field of view); {int(dark.sum())} of {k} directions are unseen"
        )
    return a


@storable
@dataclass(frozen=True)
class Design:
    """What a design matrix can and cannot measure.

    Attributes
    ----------
    matrix : ndarray, shape (N, K)
        The design matrix ``A``.
    directions : ndarray, shape (K, d)
        Source locations (rad, or length units for positions).
    singular_values : ndarray, shape (min(N, K),)
        Singular values of ``A`` in decreasing order (reading units per unit intensity).
    rank : int
        Numerical rank (singular values above ``max(N, K) * eps * s_max``).
    effective_rank : int
        Directions in intensity space measured to better than ``scale``:
        number of singular values with ``sigma / s_i < scale``.
    condition : float
        ``s_max / s_min`` over all min(N, K) singular values (inf if singular).
    null_space : ndarray, shape (K, K - rank)
        Orthonormal basis of the intensity combinations the noiseless readings
        do not depend on at all.
    null_fraction : ndarray, shape (K,)
        Squared length of each unit intensity vector ``e_k`` in the null space:
        0 = source k's intensity is fully measurable, 1 = invisible on its own.
    """

    matrix: np.ndarray
    directions: np.ndarray
    singular_values: np.ndarray
    rank: int
    effective_rank: int
    condition: float
    null_space: np.ndarray
    null_fraction: np.ndarray

    @property
    def nullity(self) -> int:
        """Dimension K - rank of the null space."""
        return int(self.matrix.shape[1] - self.rank)

    def __repr__(self) -> str:
        n, k = self.matrix.shape
        return (f"Design(N={n}, K={k}, rank={self.rank}, effective_rank={self.effective_rank}, "
                f"condition={self.condition:.3g})")


def analyse_design(
    matrix: np.ndarray, directions: np.ndarray, sigma: float, scale: float
) -> Design:
    """SVD of a design matrix: rank, conditioning and null space.

    Parameters
    ----------
    matrix : ndarray, shape (N, K)
    directions : ndarray, shape (K, d)
    sigma : float
        Noise sd of one reading, used for ``effective_rank``.
    scale : float
        Intensity scale (e.g. ``i_max``) against which a direction counts as measured.
    """
    n, k = matrix.shape
    # V (K, K) in full; U only as wide as needed (a full U is N x N: 800 MB at N = 10^4)
    _, s, vt = np.linalg.svd(matrix, full_matrices=k > n)
    tol = max(n, k) * np.finfo(float).eps * (s[0] if s.size else 0.0)
    rank = int(np.sum(s > tol))
    null = np.ascontiguousarray(vt[rank:].T)
    cond = float(s[0] / s[-1]) if s[-1] > tol else float("inf")
    for arr in (null, s):
        arr.flags.writeable = False
    return Design(
        matrix=matrix,
        directions=directions,
        singular_values=s,
        rank=rank,
        effective_rank=int(np.sum(s > sigma / scale)),
        condition=cond,
        null_space=null,
        null_fraction=np.einsum("kj,kj->k", null, null),
    )
