"""Sub-sensor horizons crossed by LM steps (compiled helpers of :mod:`.lm`).

With the clipped cosine a sub-sensor's reading has a kink where a source crosses
its 90 deg horizon (n . u = 0).  LM approaches a minimum on such a kink by ever
shorter zig-zag steps; :func:`.lm._lm_trial` instead cuts a rejected step back to
the first crossing (:func:`ring_kink`, :func:`sphere_kink`) and, once a source sits
on a horizon, deals with it there (:func:`rejected_step`).  On a ring the horizon
is a point and the source's angle is frozen.  On a sphere it is a great circle:
the source is first probed both ways along the circle and across it
(:func:`probe`), since chi^2 is smooth on either side and LM's one-sided model
cannot tell which way is down, and then held on the circle, its step kept normal
to the gradient of n . u (:func:`along_horizons`) and put back onto the circle
after every step (:func:`onto_horizons`); where a second horizon crosses the
first, the probes follow both, and with none lower the direction is frozen.
Sub-sensors with opposite normals share one horizon.
"""

from __future__ import annotations

import math

import numba

from .model import _residual

__all__: list[str] = []

#: |n . u| below which a source counts as on a sub-sensor's horizon (sphere).
ON_HORIZON = 1e-10


@numba.njit(cache=True)
def ring_kink(nrm, x, step, jt, jt2, fk):  # pragma: no cover - compiled
    """First kink crossing along a ring step: (alpha, source), alpha > 1 if none.

    A sub-sensor whose clipped cosine is positive at x but not at x + step (or
    the reverse) has its 90 deg horizon crossed by that source; alpha is the
    fraction of the step at which the first crossing happens.
    """
    best, src = 2.0, -1
    for k in range(x.size // 2):
        dth = step[2 * k]
        if fk[2 * k] or dth == 0.0:
            continue
        ig = 2 * k + 1
        for n in range(nrm.shape[1]):
            if (jt[ig, n] > 0.0) == (jt2[ig, n] > 0.0):
                continue
            psi = x[2 * k] - math.atan2(nrm[1, n], nrm[0, n])
            t = (0.5 * math.pi - psi) % math.pi if dth > 0.0 else (psi + 0.5 * math.pi) % math.pi
            a = t / abs(dth)
            if a < best:
                best, src = a, k
    return best, src


@numba.njit(cache=True)
def _cos_and_gradient(nrm, q, lon, lat):  # pragma: no cover - compiled
    """n_q . u(lon, lat) and its derivatives over lon and lat."""
    cla, sla, clo, slo = math.cos(lat), math.sin(lat), math.cos(lon), math.sin(lon)
    c = cla * clo * nrm[0, q] + cla * slo * nrm[1, q] + sla * nrm[2, q]
    c_lon = cla * (-slo * nrm[0, q] + clo * nrm[1, q])
    c_lat = -sla * (clo * nrm[0, q] + slo * nrm[1, q]) + cla * nrm[2, q]
    return c, c_lon, c_lat


@numba.njit(cache=True)
def _cos_and_slope(nrm, q, lon, lat, dlon, dlat):  # pragma: no cover - compiled
    """n_q . u(lon, lat) and its derivative along the direction (dlon, dlat)."""
    c, c_lon, c_lat = _cos_and_gradient(nrm, q, lon, lat)
    return c, c_lon * dlon + c_lat * dlat


@numba.njit(cache=True)
def _unit_gradient(nrm, q, x, b):  # pragma: no cover - compiled
    """Unit gradient of n_q . u over (lon, lat) at the source x[b]; (0, 0) if none."""
    _, c_lon, c_lat = _cos_and_gradient(nrm, q, x[b], x[b + 1])
    h = math.hypot(c_lon, c_lat)
    return (0.0, 0.0) if h == 0.0 else (c_lon / h, c_lat / h)


@numba.njit(cache=True)
def _unit(lon, lat):  # pragma: no cover - compiled
    cla = math.cos(lat)
    return cla * math.cos(lon), cla * math.sin(lon), math.sin(lat)


@numba.njit(cache=True)
def sphere_kink(nrm, x, step, jt, jt2, fk):  # pragma: no cover - compiled
    """First horizon crossing along a sphere step: (alpha, source, sub-sensor).

    As :func:`ring_kink` for sources (lon, lat, I).  The flipped sub-sensors are
    ranked by the linear interpolation of n . u between both ends of the step (no
    trigonometry per sub-sensor); the first one's crossing is then found by
    Newton's method on n . u along the step.  alpha = 0 for a source already on a
    flipped sub-sensor's horizon (|n . u| <= :data:`ON_HORIZON`), alpha > 1 if none.
    """
    best, src, sub = 2.0, -1, -1
    for k in range(x.size // 3):
        b = 3 * k
        dlon, dlat = step[b], step[b + 1]
        if (fk[b] and fk[b + 1]) or (dlon == 0.0 and dlat == 0.0):
            continue
        u0, u1, u2 = _unit(x[b], x[b + 1])
        v0, v1, v2 = _unit(x[b] + dlon, x[b + 1] + dlat)
        for n in range(nrm.shape[1]):
            if (jt[b + 2, n] > 0.0) == (jt2[b + 2, n] > 0.0):
                continue
            c0 = u0 * nrm[0, n] + u1 * nrm[1, n] + u2 * nrm[2, n]
            if abs(c0) <= ON_HORIZON:
                return 0.0, k, n
            c1 = v0 * nrm[0, n] + v1 * nrm[1, n] + v2 * nrm[2, n]
            a = c0 / (c0 - c1) if c0 != c1 else 0.5
            if a < best:
                best, src, sub = a, k, n
    if src < 0:
        return best, src, sub
    b = 3 * src
    dlon, dlat = step[b], step[b + 1]
    for _ in range(8):
        c, slope = _cos_and_slope(nrm, sub, x[b] + best * dlon, x[b + 1] + best * dlat,
                                  dlon, dlat)
        if abs(c) <= 1e-15 or slope == 0.0:
            break
        best = min(max(best - c / slope, 0.0), 1.0)
    return best, src, sub


@numba.njit(cache=True)
def _same_circle(nrm, q, r):  # pragma: no cover - compiled
    """Whether sub-sensors q and r share one horizon (parallel or opposite normals)."""
    dot = nrm[0, q] * nrm[0, r] + nrm[1, q] * nrm[1, r] + nrm[2, q] * nrm[2, r]
    return abs(dot) >= 1.0 - 1e-12


@numba.njit(cache=True)
def horizon_normal(nrm, q, x, b, hc):  # pragma: no cover - compiled
    """hc[b], hc[b + 1]: the unit gradient of n_q . u over (lon, lat) of the source at x[b]."""
    g0, g1 = _unit_gradient(nrm, q, x, b)
    if g0 == 0.0 and g1 == 0.0:
        return False
    hc[b], hc[b + 1] = g0, g1
    return True


@numba.njit(cache=True)
def _onto(nrm, q, x, b):  # pragma: no cover - compiled
    """The source at x[b] put onto sub-sensor q's horizon: u - (n . u) n, normalised.

    That is the nearest point of the great circle; its longitude is kept within pi
    of the old one.
    """
    u0, u1, u2 = _unit(x[b], x[b + 1])
    c = u0 * nrm[0, q] + u1 * nrm[1, q] + u2 * nrm[2, q]
    u0, u1, u2 = u0 - c * nrm[0, q], u1 - c * nrm[1, q], u2 - c * nrm[2, q]
    h = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if h == 0.0:
        return
    lon = math.atan2(u1, u0)
    x[b] = lon + 2.0 * math.pi * round((x[b] - lon) / (2.0 * math.pi))
    x[b + 1] = math.asin(min(max(u2 / h, -1.0), 1.0))


@numba.njit(cache=True)
def onto_horizons(nrm, x, fk, hq):  # pragma: no cover - compiled
    """Put sphere sources held on a horizon (sub-sensor hq[k] >= 0) of x back onto it.

    A held step runs along the horizon's tangent, which leaves its great circle
    at second order (:func:`_onto`).
    """
    for k in range(x.size // 3):
        b = 3 * k
        if hq[k] >= 0 and not (fk[b] and fk[b + 1]):
            _onto(nrm, hq[k], x, b)


@numba.njit(cache=True)
def _tangent(nrm, q, x, b):  # pragma: no cover - compiled
    """Unit direction in (lon, lat) along sub-sensor q's horizon at the source x[b]."""
    g0, g1 = _unit_gradient(nrm, q, x, b)
    return -g1, g0


@numba.njit(cache=True)
def renew_normals(nrm, x, fk, hq, hc):  # pragma: no cover - compiled
    """hc of every held sphere source of x: the horizon's unit normal at its point now."""
    for k in range(x.size // 3):
        b = 3 * k
        if hq[k] >= 0 and not (fk[b] and fk[b + 1]):
            horizon_normal(nrm, hq[k], x, b, hc)


@numba.njit(cache=True)
def along_horizons(ad, gm, hc, fx):  # pragma: no cover - compiled
    """Restrict the damped system (ad, gm) of sphere sources held on a horizon.

    For such a source (hc[b], hc[b + 1] a unit vector, b = 3k, neither angle
    fixed) the step in (lon, lat) is t v with v = (-hc[b + 1], hc[b]): row and
    column b become v's combination of rows and columns b, b + 1 (R^T ad R), and
    row b + 1 a fixed one.  :func:`back_to_lonlat` maps t back.
    """
    p = gm.size
    for b in range(0, p, 3):
        h0, h1 = hc[b], hc[b + 1]
        if (h0 == 0.0 and h1 == 0.0) or fx[b] or fx[b + 1]:
            continue
        v0, v1 = -h1, h0
        d = v0 * v0 * ad[b, b] + 2.0 * v0 * v1 * ad[b, b + 1] + v1 * v1 * ad[b + 1, b + 1]
        for j in range(p):
            ad[b, j] = v0 * ad[b, j] + v1 * ad[b + 1, j]
            ad[j, b] = ad[b, j]
            ad[b + 1, j] = 0.0
            ad[j, b + 1] = 0.0
        ad[b, b], ad[b + 1, b + 1], ad[b, b + 1], ad[b + 1, b] = d, 1.0, 0.0, 0.0
        gm[b], gm[b + 1] = v0 * gm[b] + v1 * gm[b + 1], 0.0


@numba.njit(cache=True)
def back_to_lonlat(step, gm, g, hc, fx):  # pragma: no cover - compiled
    """Undo :func:`along_horizons`: step (lon, lat) = t v, and gm back to g there."""
    for b in range(0, gm.size, 3):
        h0, h1 = hc[b], hc[b + 1]
        if (h0 == 0.0 and h1 == 0.0) or fx[b] or fx[b + 1]:
            continue
        t = step[b]
        step[b], step[b + 1] = -h1 * t, h0 * t
        gm[b], gm[b + 1] = g[b], g[b + 1]


#: :func:`rejected_step` outcomes: cut (or nothing), held (solve again), probe.
CUT, HELD, PROBE = 0, 1, 2


@numba.njit(cache=True)
def rejected_step(kind, nrm, x, step, jt, jt2, fk, hc, hq):  # pragma: no cover - compiled
    """After a rejected step (clipped cosine): (alpha, outcome, source, sub-sensor).

    HELD: a ring source sat on a horizon the step crossed; its angle is now frozen:
    solve again at x.  PROBE: a sphere source sits on the horizon of sub-sensor
    ``sub`` that the step crossed (and on a second one if it is held already;
    :func:`probe`).  CUT: alpha < 1 is the fraction of the step at its first
    horizon crossing (none if alpha > 1).
    """
    if kind == 0:
        alpha, src = ring_kink(nrm, x, step, jt, jt2, fk)
        if alpha <= 1.0 and alpha * abs(step[2 * src]) <= 1e-12:
            fk[2 * src] = True
            return 2.0, HELD, src, -1
        return alpha, CUT, src, -1
    alpha, src, sub = sphere_kink(nrm, x, step, jt, jt2, fk)
    if alpha > 0.0:
        return alpha, CUT, src, sub
    if hq[src] >= 0 and _same_circle(nrm, hq[src], sub):
        return 2.0, CUT, src, sub  # sliding along that horizon: a shorter step
    return 2.0, PROBE, src, sub


@numba.njit(cache=True)
def _probes(kind, law, p, nrm, pos, s, x, xn, jt2, r2, b, qa, qb, h,
            chi2):  # pragma: no cover - compiled
    """Best step below chi2 from the source at x[b] on qa's horizon: (chi2, which, evaluations).

    Directions: both ways along qa's horizon (put back onto it), both ways along
    qb's (qb >= 0, a vertex) or across qa's (qb < 0), and the four sums of those
    (into the cells between); lengths h, h / 8, ... h / 8^4 until one of a length
    lowers chi^2.  The best is left in xn; which = the sub-sensor whose horizon
    it follows, -1 off any, -2 none lower.
    """
    ta0, ta1 = _tangent(nrm, qa, x, b)
    tb0, tb1 = _tangent(nrm, qb, x, b) if qb >= 0 else (ta1, -ta0)
    best, which, lon, lat, n_eval = chi2, -2, x[b], x[b + 1], 0
    for m in range(5):
        for j in range(8):
            sa = (1.0, -1.0, 0.0, 0.0, 1.0, 1.0, -1.0, -1.0)[j]
            sb = (0.0, 0.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0)[j]
            d0, d1 = sa * ta0 + sb * tb0, sa * ta1 + sb * tb1
            nd = math.hypot(d0, d1) * 8.0 ** m / h
            if nd == 0.0:
                continue
            for i in range(x.size):
                xn[i] = x[i]
            xn[b], xn[b + 1] = x[b] + d0 / nd, x[b + 1] + d1 / nd
            q = qa if j < 2 else (qb if j < 4 else -1)
            if q >= 0:
                _onto(nrm, q, xn, b)
            c = _residual(kind, law, p, nrm, pos, xn, s, jt2, r2, False)
            n_eval += 1
            if c < best:
                best, which, lon, lat = c, q, xn[b], xn[b + 1]
        if which > -2:
            break
    for i in range(x.size):
        xn[i] = x[i]
    xn[b], xn[b + 1] = lon, lat
    return best, which, n_eval


@numba.njit(cache=True)
def probe(kind, law, p, nrm, pos, s, x, xn, jt, r, jt2, r2, fk, hc, hq, src, sub, step,
          chi2):  # pragma: no cover - compiled
    """A sphere source of x on sub-sensor sub's horizon after a rejected step: (chi2, evaluations).

    chi^2 is smooth on either side of a horizon (in each cell around a vertex of
    two), so LM's one-sided model cannot tell which way is down.  :func:`_probes`
    steps from the source (at most as far as the rejected ``step`` moved it), and
    the best lower point becomes x (jt, r evaluated there); the source is then
    held on the horizon it followed (hq, hc) or free.  If none is lower, a free
    source is held on sub's horizon and a source at a vertex gets its direction
    frozen.
    """
    b = 3 * src
    qa, qb = (hq[src], sub) if hq[src] >= 0 else (sub, -1)
    h = math.hypot(step[b], step[b + 1])
    _, q, m = _probes(kind, law, p, nrm, pos, s, x, xn, jt2, r2, b, qa, qb, h, chi2)
    hc[b], hc[b + 1] = 0.0, 0.0
    if q == -2:
        hq[src] = qa if qb < 0 else -1
        if qb >= 0 or not horizon_normal(nrm, qa, x, b, hc):
            fk[b], fk[b + 1], hq[src] = True, True, -1
        return chi2, m
    for i in range(x.size):
        x[i] = xn[i]
    hq[src] = q
    if q >= 0:
        horizon_normal(nrm, q, x, b, hc)
    return _residual(kind, law, p, nrm, pos, x, s, jt, r, True), m + 1
