"""Compiled (numba) sweep of the window moves of :mod:`olsbayes.imaging.window`.

A window move costs O(N + |B|) arithmetic per chain but about twenty small
numpy calls, whose fixed per-call overhead would dominate; this kernel runs
the same exact moves in compiled code.  Randomness comes in as pre-drawn
uniforms (one per move and chain, from the caller's Generator): each 1-D draw
is by inversion, so it is a deterministic function of its uniform.

The truncated normal is drawn by inversion in log space like
:func:`olsbayes.imaging.truncated.truncnorm_1d`: ``log Phi`` from ``erfc``
(with the asymptotic series below z = -30, relative error < 1e-11) and its
inverse by Newton's method on ``log Phi`` (upper half solved on the mirrored
tail), to ~1e-12 in z.
"""

from __future__ import annotations

import math

from .._jit import prepare

prepare()  # numba's cache folder, before numba is imported

import numba  # noqa: E402

__all__ = ["window_sweep_compiled", "truncnorm_inv"]

_SQRT2 = math.sqrt(2.0)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_FLAT = 1e-8  # as olsbayes.imaging.eigen._FLAT


@numba.njit(cache=True)
def _log_ndtr(z):  # pragma: no cover - compiled
    if z == -math.inf:
        return -math.inf
    if z > 0.0:
        return math.log1p(-0.5 * math.erfc(z / _SQRT2))
    if z > -30.0:
        return math.log(0.5 * math.erfc(-z / _SQRT2))
    z2 = 1.0 / (z * z)
    series = z2 * (-1.0 + z2 * (3.0 + z2 * (-15.0 + z2 * (105.0 - 945.0 * z2))))
    return -0.5 * z * z - math.log(-z) - _LOG_SQRT_2PI + math.log1p(series)


@numba.njit(cache=True)
def _ndtri_log(logp):  # pragma: no cover - compiled
    """z with log Phi(z) = logp (logp <= log(1/2)), by Newton's method."""
    if logp == -math.inf:
        return -math.inf
    if logp > -1.0:
        z = -1.0 + 2.0 * (logp + 1.0) / (1.0 - math.log(2.0))  # rough start
        z = min(z, 0.0)
    else:  # tail: -z^2/2 - log(-z) - log sqrt(2 pi) ~ logp
        s = -2.0 * logp
        z = -math.sqrt(max(s - math.log(max(s, 1.0)) - 2.0 * _LOG_SQRT_2PI, 1e-4))
    for _ in range(100):
        lp = _log_ndtr(z)
        slope = math.exp(-0.5 * z * z - _LOG_SQRT_2PI - lp)  # d log Phi / dz
        dz = (logp - lp) / slope
        # log Phi is concave: Newton from either side is safe with a damped cap
        dz = max(min(dz, 2.0), -2.0)
        z += dz
        if abs(dz) <= 1e-13 * (1.0 + abs(z)):
            break
    return z


@numba.njit(cache=True)
def _ndtri_exp(logp):  # pragma: no cover - compiled
    """Inverse of log Phi on the whole line (logp <= 0)."""
    if logp <= -math.log(2.0):
        return _ndtri_log(logp)
    q = -math.expm1(logp)  # upper tail 1 - p, accurate
    return -_ndtri_log(math.log(q))


@numba.njit(cache=True)
def truncnorm_inv(mean, sd, lower, upper, u):  # pragma: no cover - compiled
    """The draw of N(mean, sd^2) truncated to [lower, upper] with uniform u."""
    alpha, beta = (lower - mean) / sd, (upper - mean) / sd
    flip = alpha + beta > 0.0
    lo, hi = (-beta, -alpha) if flip else (alpha, beta)
    log_lo, log_hi = _log_ndtr(lo), _log_ndtr(hi)
    if log_hi == -math.inf or lo >= hi:
        z = lo
    else:
        diff = math.log1p(-math.exp(min(log_lo - log_hi, 0.0)))
        a_ = log_lo
        b_ = math.log(max(u, 1e-300)) + log_hi + diff
        big = max(a_, b_)
        logp = big + math.log1p(math.exp(min(a_, b_) - big)) if big > -math.inf else big
        z = min(max(_ndtri_exp(min(logp, 0.0)), lo), hi)
    if flip:
        z = -z
    return mean + sd * z


@numba.njit(cache=True)
def _line(h, prec, lo, hi, u):  # pragma: no cover - compiled
    """t ~ exp(h t - prec t^2 / 2) on [lo, hi] by inversion with uniform u."""
    w = hi - lo
    if math.isfinite(w) and prec * w * w < _FLAT:  # exponentially tilted uniform
        a = abs(h)
        if a * w < 1e-12:
            s = u * w
        else:
            s = min(max(-math.log1p(-u * -math.expm1(-a * w)) / a, 0.0), w)
        t = hi - s if h > 0 else lo + s
    elif prec <= 0.0:
        return 0.0  # improper along this line (flat and unbounded): no move
    else:
        t = truncnorm_inv(h / prec, 1.0 / math.sqrt(prec), lo, hi, u)
    return min(max(t, lo), hi)


@numba.njit(cache=True)
def window_sweep_compiled(  # pragma: no cover - compiled
    x, r, order, index, vec, response, lam, inv_s2, i_max, u
):
    """Moves ``order`` (into the WindowMoves arrays) on chains x (C, K), r (C, N) in place."""
    n_chains, width, n_obs = x.shape[0], index.shape[1], r.shape[1]
    for i in range(order.shape[0]):
        m = order[i]
        prec = lam[m] * inv_s2
        for c in range(n_chains):
            t_lo, t_hi = -math.inf, math.inf
            for j in range(width):
                v = vec[m, j]
                if v == 0.0:
                    continue
                xk = x[c, index[m, j]]
                to_lo, to_hi = -xk / v, (i_max - xk) / v
                if v > 0.0:
                    t_lo, t_hi = max(t_lo, to_lo), min(t_hi, to_hi)
                else:
                    t_lo, t_hi = max(t_lo, to_hi), min(t_hi, to_lo)
            t_lo, t_hi = min(t_lo, 0.0), max(t_hi, 0.0)
            h = 0.0
            for n in range(n_obs):
                h += r[c, n] * response[m, n]
            t = _line(h * inv_s2, prec, t_lo, t_hi, u[i, c])
            if t == 0.0:
                continue
            for n in range(n_obs):
                r[c, n] -= t * response[m, n]
            for j in range(width):
                k = index[m, j]
                x[c, k] = min(max(x[c, k] + t * vec[m, j], 0.0), i_max)
