"""Compiled (numba) sweep of the window moves of :mod:`olsbayes.imaging.window`.

A window move costs O(N + |B|) arithmetic per chain but about twenty small
numpy calls, whose fixed per-call overhead would dominate; this kernel runs
the same exact moves in compiled code.  Randomness comes in as pre-drawn
uniforms (one per move and chain, from the caller's Generator): each 1-D draw
is by inversion, so it is a deterministic function of its uniform.

The truncated normal is drawn by inversion in log space like
:func:`olsbayes.imaging.truncated.truncnorm_1d`: ``log Phi`` from ``erfc``
(with the asymptotic series below z = -30, relative error < 1e-11) and its
inverse by Wichura's rational approximations (Algorithm AS 241, Applied
Statistics 37, 477-484, 1988; about 1e-16 relative, the tails evaluated from
``log p`` so nothing underflows), by Newton's method on ``log Phi`` beyond
their range (a tail probability below 1e-300).
"""

from __future__ import annotations

import math

from .._jit import prepare

prepare()  # numba's cache folder, before numba is imported

import numba  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["window_sweep_compiled", "truncnorm_inv"]

_SQRT2 = math.sqrt(2.0)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_FLAT = 1e-8  # as olsbayes.imaging.eigen._FLAT
_LOG_TAIL_MIN = math.log(1e-300)  # AS 241's range: tail probabilities down to 1e-300

# AS 241 (Wichura 1988), PPND16: numerator and denominator coefficients, highest
# power first -- the centre, and the tails with r = sqrt(-log q) <= 5 and > 5.
_CENTRE_NUM = (
    2.5090809287301226727e+3, 3.3430575583588128105e+4, 6.7265770927008700853e+4,
    4.5921953931549871457e+4, 1.3731693765509461125e+4, 1.9715909503065514427e+3,
    1.3314166789178437745e+2, 3.3871328727963666080e+0,
)
_CENTRE_DEN = (
    5.2264952788528545610e+3, 2.8729085735721942674e+4, 3.9307895800092710610e+4,
    2.1213794301586595867e+4, 5.3941960214247511077e+3, 6.8718700749205790830e+2,
    4.2313330701600911252e+1, 1.0,
)
_NEAR_NUM = (
    7.74545014278341407640e-4, 2.27238449892691845833e-2, 2.41780725177450611770e-1,
    1.27045825245236838258e+0, 3.64784832476320460504e+0, 5.76949722146069140550e+0,
    4.63033784615654529590e+0, 1.42343711074968357734e+0,
)
_NEAR_DEN = (
    1.05075007164441684324e-9, 5.47593808499534494600e-4, 1.51986665636164571966e-2,
    1.48103976427480074590e-1, 6.89767334985100004550e-1, 1.67638483018380384940e+0,
    2.05319162663775882187e+0, 1.0,
)
_FAR_NUM = (
    2.01033439929228813265e-7, 2.71155556874348757815e-5, 1.24266094738807843860e-3,
    2.65321895265761230930e-2, 2.96560571828504891230e-1, 1.78482653991729133580e+0,
    5.46378491116411436990e+0, 6.65790464350110377720e+0,
)
_FAR_DEN = (
    2.04426310338993978564e-15, 1.42151175831644588870e-7, 1.84631831751005468180e-5,
    7.86869131145613259100e-4, 1.48753612908506148525e-2, 1.36929880922735805310e-1,
    5.99832206555887937690e-1, 1.0,
)


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
def _horner(coefs, x):  # pragma: no cover - compiled
    """The polynomial with coefficients ``coefs`` (highest power first) at x."""
    total = 0.0
    for c in coefs:
        total = total * x + c
    return total


@numba.njit(cache=True)
def _ndtri_exp(logp):  # pragma: no cover - compiled
    """Inverse of log Phi on the whole line (logp <= 0): z with log Phi(z) = logp.

    AS 241 (PPND16): a rational function of ``p - 1/2`` in the centre
    (``|p - 1/2| <= 0.425``), else of ``r = sqrt(-log q)``, q the nearer tail's
    probability (``p``, or ``1 - p = -expm1(log p)``) -- one for ``r <= 5``,
    one beyond.  Tails below 1e-300 go to Newton's method.
    """
    if logp == -math.inf:
        return -math.inf
    half = math.exp(logp) - 0.5
    if abs(half) <= 0.425:
        r = 0.180625 - half * half
        return half * _horner(_CENTRE_NUM, r) / _horner(_CENTRE_DEN, r)
    lower = half < 0.0
    log_q = logp if lower else math.log(-math.expm1(logp))
    if log_q < _LOG_TAIL_MIN:
        z = _ndtri_log(log_q)  # the nearer tail's quantile, below its mean
    else:
        r = math.sqrt(-log_q)
        if r <= 5.0:
            z = -_horner(_NEAR_NUM, r - 1.6) / _horner(_NEAR_DEN, r - 1.6)
        else:
            z = -_horner(_FAR_NUM, r - 5.0) / _horner(_FAR_DEN, r - 5.0)
    return z if lower else -z


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
def _dots(r, row, h):  # pragma: no cover - compiled
    """``h[c] = r[c] . row`` for every chain c, each sum in the order of the sensors.

    Four chains at a time in four accumulators: their additions do not wait on one
    another, and each chain's sum is, to the bit, that of its own loop.
    """
    n_chains, n_obs = r.shape
    c = 0
    while c + 4 <= n_chains:
        h0 = h1 = h2 = h3 = 0.0
        for n in range(n_obs):
            w = row[n]
            h0 += r[c, n] * w
            h1 += r[c + 1, n] * w
            h2 += r[c + 2, n] * w
            h3 += r[c + 3, n] * w
        h[c], h[c + 1], h[c + 2], h[c + 3] = h0, h1, h2, h3
        c += 4
    for c in range(c, n_chains):
        h0 = 0.0
        for n in range(n_obs):
            h0 += r[c, n] * row[n]
        h[c] = h0


@numba.njit(cache=True)
def window_sweep_compiled(  # pragma: no cover - compiled
    x, r, order, index, vec, response, lam, inv_s2, i_max, u
):
    """Moves ``order`` (into the WindowMoves arrays) on chains x (C, K), r (C, N) in place."""
    n_chains, width, n_obs = x.shape[0], index.shape[1], r.shape[1]
    h = np.empty(n_chains)
    for i in range(order.shape[0]):
        m = order[i]
        prec = lam[m] * inv_s2
        _dots(r, response[m], h)  # the chains are independent: every h before any move
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
            t = _line(h[c] * inv_s2, prec, t_lo, t_hi, u[i, c])
            if t == 0.0:
                continue
            for n in range(n_obs):
                r[c, n] -= t * response[m, n]
            for j in range(width):
                k = index[m, j]
                x[c, k] = min(max(x[c, k] + t * vec[m, j], 0.0), i_max)
