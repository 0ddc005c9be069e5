"""Compiled (numba) forward model of the LM kernel: responses and analytic Jacobians.

The three source kinds of :class:`~olsbayes.Model` (codes 0 angle, 1 lonlat,
2 position) and the laws clipped cosine (code 0) and ``max(c, 0)**p`` (code 1);
trig-free per sensor-source pair (one cos/sin per source and evaluation).  Used
by :mod:`.lm`, :mod:`.fit` and :mod:`.refine`.
"""

from __future__ import annotations

import math

import numba

_LAW_COSINE, _LAW_POWER = 0, 1


@numba.njit(cache=True)
def _power(x, p):  # pragma: no cover - compiled
    """x**p by repeated squaring of the integer part (as sensitivity._power)."""
    n = int(p)
    frac = p - n
    out, base, first = 1.0, x, True
    while n:
        if n & 1:
            out = base if first else out * base
            first = False
        n >>= 1
        if n:
            base = base * base
    if frac == 0.5:
        out *= math.sqrt(x)
    elif frac != 0.0:
        out *= x**frac
    return out


@numba.njit(cache=True)
def _law(c, law, p):  # pragma: no cover - compiled
    """g(c) and dg/dc of the clipped cosine (law 0) or max(c, 0)**p (law 1)."""
    cp = c if c > 0.0 else 0.0
    if law == _LAW_COSINE:
        return cp, 1.0 if cp > 0.0 else 0.0
    return _power(cp, p), p * _power(cp, p - 1.0)


@numba.njit(cache=True)
def _eval_ring_cosine(nrm, x, jt, want_jac):  # pragma: no cover - compiled
    """:func:`_eval_far` for the planar ring and the clipped cosine (branch-free loops)."""
    for k in range(x.size // 2):
        u0, u1, inten = math.cos(x[2 * k]), math.sin(x[2 * k]), x[2 * k + 1]
        ig, ia = 2 * k + 1, 2 * k  # (no row views: each costs reference counting)
        if want_jac:
            for n in range(nrm.shape[1]):
                c = u0 * nrm[0, n] + u1 * nrm[1, n]
                dc = -u1 * nrm[0, n] + u0 * nrm[1, n]
                jt[ig, n] = max(c, 0.0)
                jt[ia, n] = inten * dc if c > 0.0 else 0.0
        else:
            for n in range(nrm.shape[1]):
                jt[ig, n] = max(u0 * nrm[0, n] + u1 * nrm[1, n], 0.0)


@numba.njit(cache=True)
def _eval_sphere_cosine(nrm, x, jt, want_jac):  # pragma: no cover - compiled
    """:func:`_eval_far` for the sphere and the clipped cosine (branch-free loops).

    The same operations in the same order as the general loop (the products of
    the trigonometric factors taken once per source, as the general loop's
    left-to-right products take them), so the same numbers, up to the sign of a
    zero at unlit sensors.
    """
    for k in range(x.size // 3):
        b = 3 * k
        inten = x[b + 2]
        cla, sla = math.cos(x[b + 1]), math.sin(x[b + 1])
        clo, slo = math.cos(x[b]), math.sin(x[b])
        u0, u1, u2 = cla * clo, cla * slo, sla
        if want_jac:
            a0, a1 = -cla * slo, cla * clo  # d c / d lon = a0 n0 + a1 n1
            b0, b1 = -sla * clo, sla * slo  # d c / d lat = b0 n0 - b1 n1 + cla n2
            for n in range(nrm.shape[1]):
                c = u0 * nrm[0, n] + u1 * nrm[1, n] + u2 * nrm[2, n]
                lit = c > 0.0
                jt[b + 2, n] = c if lit else 0.0
                jt[b, n] = inten * (a0 * nrm[0, n] + a1 * nrm[1, n]) if lit else 0.0
                jt[b + 1, n] = (inten * (b0 * nrm[0, n] - b1 * nrm[1, n] + cla * nrm[2, n])
                                if lit else 0.0)
        else:
            for n in range(nrm.shape[1]):
                c = u0 * nrm[0, n] + u1 * nrm[1, n] + u2 * nrm[2, n]
                jt[b + 2, n] = c if c > 0.0 else 0.0


@numba.njit(cache=True)
def _eval_far(kind, law, p, nrm, x, jt, want_jac):  # pragma: no cover - compiled
    """Rows of jt (P, N): g(c) per source, and with want_jac the location rows."""
    d1 = 2 if kind == 0 else 3
    if kind == 0 and law == _LAW_COSINE:
        _eval_ring_cosine(nrm, x, jt, want_jac)
        return
    if kind == 1 and law == _LAW_COSINE:
        _eval_sphere_cosine(nrm, x, jt, want_jac)
        return
    for k in range(x.size // d1):
        b = k * d1
        inten = x[b + d1 - 1]
        if kind == 0:
            u0, u1, u2 = math.cos(x[b]), math.sin(x[b]), 0.0
        else:
            cla, sla = math.cos(x[b + 1]), math.sin(x[b + 1])
            clo, slo = math.cos(x[b]), math.sin(x[b])
            u0, u1, u2 = cla * clo, cla * slo, sla
        for n in range(nrm.shape[1]):
            if kind == 0:
                c = u0 * nrm[0, n] + u1 * nrm[1, n]
            else:
                c = u0 * nrm[0, n] + u1 * nrm[1, n] + u2 * nrm[2, n]
            g, dg = _law(c, law, p)
            jt[b + d1 - 1, n] = g
            if want_jac:
                w = inten * dg
                if kind == 0:
                    jt[b, n] = w * (-u1 * nrm[0, n] + u0 * nrm[1, n])
                else:
                    jt[b, n] = w * (-cla * slo * nrm[0, n] + cla * clo * nrm[1, n])
                    jt[b + 1, n] = w * (-sla * clo * nrm[0, n] - sla * slo * nrm[1, n]
                                        + cla * nrm[2, n])


@numba.njit(cache=True)
def _eval_near(law, p, nrm, pos, x, jt, want_jac):  # pragma: no cover - compiled
    """As :func:`_eval_far` for near sources (positions): g(c) / r^2 and its gradient."""
    for k in range(x.size // 4):
        b = k * 4
        inten = x[b + 3]
        for n in range(nrm.shape[1]):
            d0, d1, d2 = x[b] - pos[0, n], x[b + 1] - pos[1, n], x[b + 2] - pos[2, n]
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            r = math.sqrt(r2)
            c = (d0 * nrm[0, n] + d1 * nrm[1, n] + d2 * nrm[2, n]) / r
            g, dg = _law(c, law, p)
            jt[b + 3, n] = g / r2
            if want_jac:
                e, f = dg / r2, 2.0 * g / (r2 * r2)
                cr = c / r2
                jt[b, n] = inten * (e * (nrm[0, n] / r - cr * d0) - f * d0)
                jt[b + 1, n] = inten * (e * (nrm[1, n] / r - cr * d1) - f * d1)
                jt[b + 2, n] = inten * (e * (nrm[2, n] / r - cr * d2) - f * d2)


@numba.njit(cache=True)
def _residual(kind, law, p, nrm, pos, x, s, jt, r, want_jac):  # pragma: no cover
    """Fill jt (intensity rows, + location rows if want_jac) and r = s - response; chi^2."""
    if kind == 2:
        _eval_near(law, p, nrm, pos, x, jt, want_jac)
    else:
        _eval_far(kind, law, p, nrm, x, jt, want_jac)
    d1 = kind + 2
    for n in range(s.size):
        r[n] = 0.0
    for k in range(x.size // d1):  # r = response, summed over sources in order
        row = k * d1 + d1 - 1
        for n in range(s.size):
            r[n] += jt[row, n] * x[row]
    for n in range(s.size):
        r[n] = s[n] - r[n]
    return _sumsq(r)


@numba.njit(cache=True)
def _sumsq(r):  # pragma: no cover - compiled
    """Sum of squares, added in order."""
    acc = 0.0
    for n in range(r.size):
        acc += r[n] * r[n]
    return acc
