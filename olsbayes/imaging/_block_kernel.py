"""Compiled (numba) exact-HMC trajectories of the block moves of :mod:`olsbayes.imaging.block`.

The same dynamics as :func:`olsbayes.imaging.truncated.trajectory` -- every
coordinate on ``x(t) = mu + a cos t + v sin t``, the earliest wall crossing in
closed form, a bounce reflecting the velocity in the covariance metric,
``v <- v - 2 v_k S[:, k] / S[k, k]`` -- one chain at a time.  A trajectory
bounces a few hundred times; each bounce is O(L) arithmetic, which numpy would
spend in per-call overhead.
"""

from __future__ import annotations

import math

from .._jit import prepare

prepare()  # numba's cache folder, before numba is imported

import numba  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["trajectories_compiled"]

_TINY_T = 1e-12  # as olsbayes.imaging.truncated._TINY_T
_TAU = 2.0 * math.pi
_SLACK = 1e-9  # relative width added to the wall screen of _first_wall
_SURE = 1.0 + 1e-9  # widens the travel-time bound of _first_wall past rounding


@numba.njit(cache=True)
def _hit(a, v, h, lower):  # pragma: no cover - compiled
    """Time of the next crossing of level h by ``a cos t + v sin t`` (going down if lower)."""
    r = math.hypot(a, v)
    c = h / r if r > 0.0 else math.inf
    if not abs(c) < 1.0:
        return math.inf
    phi = math.atan2(v, a)
    return (phi + math.acos(c)) % _TAU if lower else (phi - math.acos(c)) % _TAU


@numba.njit(cache=True)
def _first_wall(a, v, h_lo, h_hi, left):  # pragma: no cover - compiled
    """Earliest wall crossing: (t, coordinate, is_upper); t = inf when none before ``left``.

    The crossing time of a coordinate (hypot, atan2, acos: most of a bounce's cost)
    is solved only where it can beat both ``left`` and the earliest so far:

    * over ``[0, left]`` with ``left < pi``, ``a cos t + v sin t`` turns at most
      once, so its range is that of its two end values, widened to the amplitude
      ``-r`` (or ``r``) where its velocity turns from down to up (up to down)
      inside; a coordinate whose range misses a wall cannot reach it in time;
    * its speed never exceeds ``r <= |a| + |v|``, so a wall ``d`` away takes at
      least ``d / (|a| + |v|)``.

    Both screens are widened past rounding, so every crossing that could be the
    earliest is solved by the same formula in the same order: the result is, to
    the bit, that of solving every coordinate.
    """
    best, kb, upb = math.inf, -1, False
    cl, sl = math.cos(left), math.sin(left)
    short = left < math.pi  # at most one turn: the end values bound the range
    for j in range(a.shape[0]):
        aj, vj = a[j], v[j]
        end = aj * cl + vj * sl
        low, high = min(aj, end), max(aj, end)
        slope = vj * cl - aj * sl  # velocity at t = left
        if vj < 0.0 < slope or not short:
            low = -math.hypot(aj, vj)
        if slope < 0.0 < vj or not short:
            high = math.hypot(aj, vj)
        speed = abs(aj) + abs(vj)  # bounds the amplitude r, hence the speed
        slack = _SLACK * speed
        if low <= h_lo[j] + slack and abs(aj - h_lo[j]) < best * speed * _SURE:
            t = _hit(aj, vj, h_lo[j], True)
            if _TINY_T <= t < best:
                best, kb, upb = t, j, False
        if high >= h_hi[j] - slack and abs(h_hi[j] - aj) < best * speed * _SURE:
            t = _hit(aj, vj, h_hi[j], False)
            if _TINY_T <= t < best:
                best, kb, upb = t, j, True
    return best, kb, upb


@numba.njit(cache=True)
def trajectories_compiled(  # pragma: no cover - compiled
    x, mu, v, cov, lower, upper, t_total, max_bounces
):
    """End points (C, L) (NaN rows: stopped at ``max_bounces``) and bounces (C,)."""
    n_chains, dim = x.shape
    out = np.empty_like(x)
    bounces = np.zeros(n_chains, dtype=np.int64)
    h_lo = np.empty(dim)
    h_hi = np.empty(dim)
    for c in range(n_chains):
        a = x[c] - mu[c]
        vel = v[c].copy()
        for j in range(dim):
            h_lo[j] = lower[j] - mu[c, j]
            h_hi[j] = upper[j] - mu[c, j]
        left = t_total
        nb = 0
        while True:
            t, k, up = _first_wall(a, vel, h_lo, h_hi, left)
            if t >= left:
                ct, st = math.cos(left), math.sin(left)
                for j in range(dim):
                    out[c, j] = mu[c, j] + a[j] * ct + vel[j] * st
                break
            nb += 1
            if nb > max_bounces:
                out[c, :] = np.nan
                break
            ct, st = math.cos(t), math.sin(t)
            for j in range(dim):
                pos = a[j] * ct + vel[j] * st
                vel[j] = -a[j] * st + vel[j] * ct
                a[j] = pos
            a[k] = h_hi[k] if up else h_lo[k]
            f = 2.0 * vel[k] / cov[k, k]
            for j in range(dim):
                vel[j] -= f * cov[k, j]
            left -= t
        bounces[c] = nb
    return out, bounces
