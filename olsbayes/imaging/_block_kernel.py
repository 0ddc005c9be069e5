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


@numba.njit(cache=True)
def _first_wall(a, v, h_lo, h_hi):  # pragma: no cover - compiled
    """Earliest wall crossing: (t, coordinate, is_upper); t = inf when none."""
    best, kb, upb = math.inf, -1, False
    for j in range(a.shape[0]):
        r = math.hypot(a[j], v[j])
        if r == 0.0:
            continue
        phi = math.atan2(v[j], a[j])
        c = h_lo[j] / r
        if abs(c) < 1.0:
            t = (phi + math.acos(c)) % _TAU
            if _TINY_T <= t < best:
                best, kb, upb = t, j, False
        c = h_hi[j] / r
        if abs(c) < 1.0:
            t = (phi - math.acos(c)) % _TAU
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
            t, k, up = _first_wall(a, vel, h_lo, h_hi)
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
