"""Compiled (numba) bounded Levenberg–Marquardt: twin of :mod:`olsbayes.ml.lm`.

The numpy :func:`~olsbayes.ml.lm.refine_batch_numpy` advances all trials in
lock-step, and for the small problems of ML fitting (P <= ~16 parameters, N ~
30 sub-sensors, ~10 candidates) its cost is numpy's per-call overhead, not
arithmetic.  This module runs the *same* algorithm one trial at a time in
compiled code: the same damping schedule, stopping rule, bounds (intensity >=
0 with the at-bound active set, |lat| <= pi/2, plate z >= floor), frozen
parameters and evaluation count, so both paths reach the same optimum (they
differ only in rounding: a different summation order and an LU solve instead
of LAPACK's).

The forward model and its analytic Jacobian are evaluated in-kernel for the
three source kinds of :class:`~olsbayes.Model` and the laws
:class:`~olsbayes.sensitivity.Cosine` and
:class:`~olsbayes.sensitivity.CosinePower` (:mod:`.model`); trig-free
per sensor-source pair (one cos/sin per source and iteration).  Other laws take
the numpy path.

Options used by the fast fit: ``kinks`` cuts rejected steps at the sub-sensor
horizons of a ring or sphere with the clipped cosine and holds sources on them
(:func:`_lm_trial`, :mod:`.horizons`); runs of a group
stop at optima found before (:class:`~olsbayes.ml.lm.Dedupe`), and on such a ring
also on entering the linear cell of one (:mod:`.cells`).

Trials are independent and run serially (deterministic; a batch equals a loop
of single calls bit for bit).  Compiled once per machine (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...model import Model
from ...sensitivity import CosinePower, is_clipped_cosine
from ..damping import DOWN, EIG_FLOOR, FLOOR, MAX, START, UP
from . import kernel_array
from .cells import _cell, _known_cell
from .horizons import (
    CUT,
    PROBE,
    along_horizons,
    back_to_lonlat,
    onto_horizons,
    probe,
    rejected_step,
    renew_normals,
)
from .linalg import _solve_spd
from .model import _LAW_COSINE, _LAW_POWER, _residual

__all__ = ["KINDS", "law_code", "lm_batch", "supports"]

#: Source kinds covered, in the order of their integer codes.
KINDS = ("angle", "lonlat", "position")


def law_code(model: Model) -> tuple[int, float] | None:
    """(code, exponent) of the model's law if the kernel implements it, else None."""
    law = model.sensitivity
    if is_clipped_cosine(law):
        return _LAW_COSINE, 1.0
    if type(law) is CosinePower:
        return _LAW_POWER, float(law.p)
    return None


def supports(model: Model) -> bool:
    """Whether :func:`lm_batch` covers this model (kind and sensitivity law)."""
    return model.kind in KINDS and law_code(model) is not None


@numba.njit(cache=True)
def _over_pole(x, b):  # pragma: no cover - compiled
    """(lon, lat) at x[b], x[b + 1] with |lat| > pi/2 carried over the pole (same direction)."""
    lat = x[b + 1]
    if abs(lat) <= 0.5 * math.pi:
        return
    lat = (lat + math.pi) % (2.0 * math.pi) - math.pi
    if abs(lat) > 0.5 * math.pi:
        lat = math.copysign(math.pi, lat) - lat
        x[b] = x[b] + math.pi if x[b] <= 0.0 else x[b] - math.pi
    x[b + 1] = lat


@numba.njit(cache=True)
def _project(kind, zfl, x):  # pragma: no cover - compiled
    """Feasible set in place: intensity >= 0, |lat| <= pi/2 (over the pole), z >= zfl."""
    d1 = kind + 2
    for k in range(x.size // d1):
        b = k * d1
        if x[b + d1 - 1] < 0.0:
            x[b + d1 - 1] = 0.0
        if kind == 1:
            _over_pole(x, b)
        elif kind == 2 and x[b + 2] < zfl:
            x[b + 2] = zfl


@numba.njit(cache=True)
def _propose(kind, zfl, nrm, x, step, scale, xn, fk, hq, held):  # pragma: no cover - compiled
    """xn = x + scale * step, made feasible, held sphere sources put back on their horizons."""
    for i in range(x.size):
        xn[i] = x[i] + scale * step[i]
    _project(kind, zfl, xn)
    if held:
        onto_horizons(nrm, xn, fk, hq)


@numba.njit(cache=True, fastmath={"reassoc"})
def _normal_eq(jt, r, a, g):  # pragma: no cover - compiled
    """a = jt jt^T (P, P) and g = jt r (P,).

    The sums over sensors may be reassociated (SIMD partial sums): a rounding-level
    difference only, like any BLAS; deterministic for a given machine.
    """
    m, n = jt.shape
    for i in range(m):
        acc = 0.0
        for t in range(n):
            acc += jt[i, t] * r[t]
        g[i] = acc
        for j in range(i + 1):
            acc = 0.0
            for t in range(n):
                acc += jt[i, t] * jt[j, t]
            a[i, j] = acc
            a[j, i] = acc


@numba.njit(cache=True)
def _damped_step(a, g, x, fz, lam, d1, ad, gm, fx, step, hc, held):  # pragma: no cover
    """Damped, bounded Gauss–Newton step into ``step``; returns the predicted decrease.

    Fixed parameters (frozen, or an intensity at 0 whose gradient points
    outwards) get a zero step, as in batch._lm_step.  With ``held`` (sphere
    horizons handled), a source with a nonzero unit vector (hc[b], hc[b + 1])
    moves normal to it, along a horizon (:func:`.horizons.along_horizons`).
    """
    p = g.size
    top = 0.0
    for i in range(p):
        top = max(top, a[i, i])
    floor = EIG_FLOOR * max(top, 1e-300)
    for i in range(p):
        fx[i] = fz[i]
    for i in range(d1 - 1, p, d1):  # intensities at the bound, gradient outwards
        fx[i] = fx[i] or (x[i] <= 0.0 and g[i] <= 0.0)
    for i in range(p):  # one pass: damped copy with fixed rows/columns cleared
        if fx[i]:
            gm[i] = 0.0
            for j in range(p):
                ad[i, j] = 0.0
            ad[i, i] = 1.0
        else:
            gm[i] = g[i]
            for j in range(p):
                ad[i, j] = 0.0 if fx[j] else a[i, j]
            ad[i, i] = a[i, i] + lam * max(a[i, i], floor)
    if held:
        along_horizons(ad, gm, hc, fx)
    _solve_spd(ad, gm, step)
    if held:
        back_to_lonlat(step, gm, g, hc, fx)
    pred = 0.0
    for i in range(p):
        acc = 0.0
        for j in range(p):
            acc += a[i, j] * step[j]
        pred += step[i] * (2.0 * gm[i] - acc)
    return pred


@numba.njit(cache=True)
def _near(known, n_known, x, tol):  # pragma: no cover - compiled
    """Whether x is within tol (max norm) of one of the rows known[:n_known]."""
    for j in range(n_known):
        far = False
        for i in range(x.size):
            if abs(x[i] - known[j, i]) > tol:
                far = True
                break
        if not far:
            return True
    return False


@numba.njit(cache=True)
def _lm_trial(kind, law, p, nrm, pos, zfl, s, x, fz, max_iter, ftol, w,
              kinks, known, n_known, tol, cells, known_vis, known_ok):  # pragma: no cover
    """Bounded LM of one trial from x (in place); returns (chi2, n_iter, converged, stalled).

    w: workspace arrays (jt, r, jt2, r2, a, ad, g, gm, step, x_new, fx, fk, hc, hq).  Proposals
    are evaluated with their Jacobian, so an accepted step needs no re-evaluation
    (the same numbers as evaluating again at the new point); after a rejected
    step the normal equations at x are reused.

    ``kinks`` (ring or sphere, clipped cosine): a rejected step that carries a
    source across a sub-sensor's horizon is cut back to the first crossing
    (accepted if it lowers chi^2).  Without this LM approaches a minimum on a
    kink by ever shorter zig-zag steps (~100 evaluations instead of ~10 at sigma
    = 0.1).  A ring source already on the horizon whose step is rejected gets its
    angle frozen for the rest of the run.  A sphere source there is probed
    (:func:`.horizons.probe`): it moves to the best lower point along or off the
    horizon, and if none is lower it is held on the horizon, sliding along its
    great circle (put back onto it after every step), or frozen where two
    horizons cross.

    Known optima (rows of ``known[:n_known]``, converged runs of the same data):
    a run whose accepted iterate comes within ``tol`` (max norm) of one stops
    there (converged; its chi^2 is not below that optimum's but for rounding);
    with ``cells`` (ring, clipped cosine) a run whose accepted iterate lies in the
    linear cell of one (``known_vis``, ``known_ok``: :func:`.cells._cell`) stops with that
    optimum as its result.
    """
    jt, r, jt2, r2, a, ad, g, gm, step, xn, fx, fk, hc, hq = w
    d1 = kind + 2
    kinks = kinks and kind <= 1 and law == _LAW_COSINE
    held = kinks and kind == 1
    for i in range(x.size):
        fk[i], hc[i], hq[i] = fz[i], 0.0, -1
    lam, extra = START, 0
    chi2_old = _residual(kind, law, p, nrm, pos, x, s, jt, r, True)
    _normal_eq(jt, r, a, g)
    for it in range(max_iter):
        pred = _damped_step(a, g, x, fk, lam, d1, ad, gm, fx, step, hc, held)
        _propose(kind, zfl, nrm, x, step, 1.0, xn, fk, hq, held)
        chi2_new = _residual(kind, law, p, nrm, pos, xn, s, jt2, r2, True)
        tiny = ftol * chi2_old + 1e-30
        acc = chi2_new < chi2_old
        cut = False
        if kinks and not acc:
            alpha, how, src, sub = rejected_step(kind, nrm, x, step, jt, jt2, fk, hc, hq)
            if how == PROBE:
                chi2_old, m = probe(kind, law, p, nrm, pos, s, x, xn, jt, r, jt2, r2, fk, hc, hq,
                                    src, sub, step, chi2_old)
                extra += (m + 1) // 2  # evaluations, counted as iterations of two
                _normal_eq(jt, r, a, g)
            if how != CUT:
                continue
            if alpha < 1.0:
                _propose(kind, zfl, nrm, x, step, alpha, xn, fk, hq, held)
                chi2_new = _residual(kind, law, p, nrm, pos, xn, s, jt2, r2, True)
                acc = cut = chi2_new < chi2_old
        small = not cut and ((acc and chi2_old - chi2_new <= tiny) or pred <= tiny)
        if acc:
            x[:] = xn
            if held:
                renew_normals(nrm, x, fk, hq, hc)
            if not cut:
                lam = max(lam / DOWN, FLOOR)
            if _near(known, n_known, x, tol):
                return chi2_new, it + 1 + extra, True, False
            j = _known_cell(jt2, known_vis, known_ok, n_known) if cells else -1
            if j >= 0:  # the run would end at that optimum: report it
                x[:] = known[j]
                chi2_new = _residual(kind, law, p, nrm, pos, x, s, jt2, r2, False)
                return chi2_new, it + 1 + extra, True, False
        else:
            lam *= UP
        stall = lam > MAX and not small
        if small or stall:
            return (chi2_new if acc else chi2_old), it + 1 + extra, True, stall
        if acc:
            jt, jt2, r, r2, chi2_old = jt2, jt, r2, r, chi2_new
            _normal_eq(jt, r, a, g)
    return _residual(kind, law, p, nrm, pos, x, s, jt, r, False), max_iter + extra, False, False


@numba.njit(cache=True)
def _lm_all(kind, law, p, nrm, pos, zfl, data, x, frozen, max_iter, ftol, kinks, group,
            base, tol, cells, chi2, n_iter, conv, stalled):  # pragma: no cover - compiled
    """:func:`_lm_trial` for every row of x (T, P) in place, outputs per trial.

    Rows come in groups of ``group`` runs on the same data; with tol > 0 a run
    stops on reaching (within tol) the optimum of an earlier converged,
    unstalled run of its group, or the group's row of ``base`` (T / group, P)
    if that has no NaN.
    """
    t, np_ = x.shape
    n = (data.shape[1] + 15) // 16 * 16  # zero-padded: the sums over sensors in
    # _normal_eq then have no scalar remainder loop
    w = (np.zeros((np_, n)), np.zeros(n), np.zeros((np_, n)), np.zeros(n),
         np.empty((np_, np_)), np.empty((np_, np_)), np.empty(np_), np.empty(np_),
         np.empty(np_), np.empty(np_), np.empty(np_, np.bool_), np.empty(np_, np.bool_),
         np.zeros(np_), np.full(np_, -1, np.int64))
    known = np.empty((group + 1, np_))
    cells = cells and kinks and kind == 0 and law == _LAW_COSINE
    known_vis = np.zeros((group + 1, np_ // 2 if cells else 0, data.shape[1]), np.bool_)
    known_ok = np.zeros(group + 1, np.bool_)
    n_known = 0
    for i in range(t):
        if i % group == 0:
            n_known = 0
            if tol > 0.0 and not np.isnan(base[i // group, 0]):
                known[0] = base[i // group]
                known_ok[0] = cells and _cell(nrm, known[0], known_vis[0])
                n_known = 1
        _project(kind, zfl, x[i])
        c, m, ok, st = _lm_trial(kind, law, p, nrm, pos, zfl, data[i], x[i], frozen[i],
                                 max_iter, ftol, w, kinks, known, n_known, tol, cells,
                                 known_vis, known_ok)
        chi2[i], n_iter[i], conv[i], stalled[i] = c, m, ok, st
        if tol > 0.0 and ok and not st and not _near(known, n_known, x[i], 0.0):
            known[n_known] = x[i]
            known_ok[n_known] = cells and _cell(nrm, x[i], known_vis[n_known])
            n_known += 1


def lm_batch(
    model: Model, data: np.ndarray, x0: np.ndarray, max_iter: int, ftol: float,
    frozen: np.ndarray | None, z_floor: float, kinks: bool = False, dedupe=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Run the compiled LM over data (T, N) from x0 (T, P) for a supported model.

    ``kinks``: cut steps at sub-sensor horizons (ring or sphere, clipped cosine;
    see :func:`_lm_trial`).  ``dedupe`` (:class:`~olsbayes.ml.lm.Dedupe`): runs of a
    group (consecutive rows on the same data) stop at known optima (:func:`_lm_all`).

    Returns x (T, P), chi2 (T,), converged (T,), n_evaluations (T,) (two per
    iteration, as the numpy path counts) and stalled (T,).  Arguments are
    coerced to one set of array types so that a single compiled signature serves.
    """
    kind, code, p, nrm, pos = _arrays(model)
    t = x0.shape[0]
    x = np.array(x0, dtype=np.float64, order="C")  # always a fresh writeable copy
    s = kernel_array(data, np.float64)
    fz = (np.zeros(x.shape, np.bool_) if frozen is None
          else kernel_array(frozen, np.bool_))
    chi2, n_iter = np.empty(t), np.empty(t, np.int64)
    conv, stalled = np.empty(t, np.bool_), np.empty(t, np.bool_)
    group, tol, cells = (1, 0.0, False) if dedupe is None else (
        dedupe.group, dedupe.tol, dedupe.cells)
    base = None if dedupe is None else dedupe.base
    b = (np.full((1, x.shape[1]), np.nan) if base is None
         else kernel_array(base, np.float64))
    if tol > 0.0 and b.shape[0] != t // group and base is not None:
        raise ValueError(f"lm_batch: {t} rows, group {group}, base rows {b.shape[0]}")
    if base is None and tol > 0.0:
        b = np.full((t // group, x.shape[1]), np.nan)
    _lm_all(kind, code, p, nrm, pos, float(z_floor), s, x, fz, int(max_iter), float(ftol),
            bool(kinks), int(group), b, float(tol), bool(cells and tol > 0.0), chi2, n_iter,
            conv, stalled)
    return x, chi2, conv, 2 * n_iter, stalled


def _arrays(model: Model) -> tuple[int, int, float, np.ndarray, np.ndarray]:
    """Kernel arguments describing a model (kind, law, exponent, normals, positions).

    Cached on the model (:meth:`~olsbayes.Model.memo`); writeable copies, so that
    every call has the same array types (one compiled signature).
    """
    def make() -> tuple[int, int, float, np.ndarray, np.ndarray]:
        code, p = law_code(model)
        nrm = np.array(model.array.normals.T, dtype=np.float64, order="C")  # (D, N)
        pos = model.array.positions
        pos = np.zeros((3, 1)) if pos is None else np.array(pos.T, dtype=np.float64, order="C")
        return KINDS.index(model.kind), code, p, nrm, pos

    return model.memo("lm_arrays", make)
