"""Angles on the circle: wrapping, circular means, the largest-gap cut, unwrapping.

One home for the circular arithmetic that ring angles and sphere longitudes need
everywhere (fits, posteriors, scores, plots).  Angles are in rad; "wrapped" means
in the interval (-pi, pi].
"""

from __future__ import annotations

import numpy as np

__all__ = ["TWO_PI", "wrap_angle", "circular_mean", "largest_gap_cut", "unwrap_around"]

TWO_PI = 2.0 * np.pi

#: Arrays of at most this many angles are wrapped by numpy's ``mod`` itself (a fit's
#: few sources: one ufunc call instead of three, about 3 us against 10 us).
_SMALL = 64


def wrap_angle(x: np.ndarray | float) -> np.ndarray:
    """Angles (rad) wrapped to the interval (-pi, pi], same shape as ``x``.

    ``pi - mod(pi - x, 2 pi)``.  On arrays of more than a few angles the floored
    modulus is taken as numpy's ``mod`` takes it -- the truncated remainder ``fmod``,
    plus 2 pi where it is negative (a zero remainder's sign does not reach the
    result) -- in place on one temporary: the same numbers, without ``mod``'s floor
    division.
    """
    x = np.asarray(x, dtype=float)
    if x.size <= _SMALL:  # one ufunc call: cheaper than three on a few angles
        return np.pi - np.mod(np.pi - x, TWO_PI)
    y = np.subtract(np.pi, x)
    np.fmod(y, TWO_PI, out=y)
    np.add(y, TWO_PI, out=y, where=y < 0)
    return np.subtract(np.pi, y, out=y)


def circular_mean(a: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Circular mean of angles ``a`` (rad) along ``axis``, wrapped to (-pi, pi].

    ``atan2(mean sin a, mean cos a)``: the direction of the mean unit vector.
    """
    a = np.asarray(a, dtype=float)
    return wrap_angle(np.arctan2(np.sin(a).mean(axis=axis), np.cos(a).mean(axis=axis)))


def largest_gap_cut(angles: np.ndarray) -> float:
    """The angle (rad) in the middle of the largest gap between ``angles``.

    Cutting the circle there keeps a cluster of angles in one piece.  With no
    angles the cut is at pi, the usual edge of (-pi, pi].
    """
    a = np.sort(wrap_angle(np.ravel(angles)))
    if a.size == 0:
        return float(np.pi)
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    i = int(np.argmax(gaps))
    return float(wrap_angle(a[i] + gaps[i] / 2))


def unwrap_around(values: np.ndarray, centre: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Periodic columns as ``centre + wrap(value - centre)``, the others unchanged.

    Parameters
    ----------
    values : ndarray, shape (..., P)
    centre : ndarray, shape (P,)
        The centre of each column (used on the periodic ones only).
    periodic : ndarray of bool, shape (P,)
        Which columns are angles.

    Returns
    -------
    ndarray, shape (..., P)
        A copy; periodic columns lie within pi of their centre, continuous across
        the +-pi edge.
    """
    out = np.array(values, dtype=float)
    c = np.asarray(centre, dtype=float)[periodic]
    out[..., periodic] = c + wrap_angle(out[..., periodic] - c)
    return out
