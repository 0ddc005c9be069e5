"""Bounded Levenberg–Marquardt refinement of Eq. 2 for a batch of starts.

All trials advance in lock-step with numpy broadcasting over a leading trial
axis: one call of ``model.response`` / ``model.jacobian`` on a (T, P) array per
iteration, a batched (T, P, P) solve, and per-trial damping.  Trials that have
met the stopping rule drop out of the active set, so the cost follows the
slowest trial only in iterations, not in work.

Bounds: intensities >= 0 (active set: an intensity at 0 whose gradient points
outwards is frozen for that step), latitudes in [-pi/2, pi/2] (a step past a
pole is carried over it), plate z > 0.

:func:`refine_batch` runs the same algorithm compiled, one trial at a time
(:mod:`olsbayes.ml._numba.lm`), for the models the kernel covers (ring, sphere
and plate with the clipped cosine or cos^p laws): for a few candidates of a
small model numpy's per-call overhead dominates the lock-step version.  The
numpy version :func:`refine_batch_numpy` is the reference and serves the other
laws (:class:`~olsbayes.CustomSensitivity`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..model import Model
from . import damping
from .outcome import FitOutcome

__all__ = ["Dedupe", "project", "refine_batch", "refine_batch_numpy", "z_floor"]

#: Jacobian entries (trials x P x N) per block of an LM iteration on a large
#: batch (see :func:`_propose`): ~1 MiB, so the intermediates stay in cache.
_BLOCK_TERMS = 131072


def z_floor(model: Model) -> float:
    """Smallest source height z above a plate (1e-6 of its extent): the LM's bound."""
    pos = model.array.positions
    scale = float(np.ptp(pos[:, :2])) if pos is not None else 1.0
    return 1e-6 * max(scale, 1e-12)


def project(model: Model, x: np.ndarray) -> np.ndarray:
    """Map parameters onto the feasible set (intensity >= 0, |lat| <= pi/2, z > 0).

    Latitudes beyond a pole are carried over it (:func:`_over_pole`).
    """
    return _project_inplace(model, np.array(x, dtype=float))


def _project_inplace(model: Model, x: np.ndarray) -> np.ndarray:
    d1 = model.n_loc + 1
    np.maximum(x[..., d1 - 1 :: d1], 0.0, out=x[..., d1 - 1 :: d1])
    if model.kind == "lonlat":
        _over_pole(x[..., 0::d1], x[..., 1::d1])
    elif model.kind == "position":
        x[..., 2::d1] = np.maximum(x[..., 2::d1], z_floor(model))
    return x


def _over_pole(lon: np.ndarray, lat: np.ndarray) -> None:
    """Carry directions with |lat| > pi/2 over the pole, in place (the same direction).

    The sphere has no edge at a pole: a step past one lands at latitude
    ``+-pi - lat`` on the opposite meridian (lon +- pi).  Clipping the latitude
    instead would leave a source at the pole, where the longitude has no effect,
    and the fit creeping along that artificial bound.
    """
    over = np.abs(lat) > np.pi / 2
    if not over.any():
        return
    t = np.mod(lat[over] + np.pi, 2 * np.pi) - np.pi
    flip = np.abs(t) > np.pi / 2
    t[flip] = np.copysign(np.pi, t[flip]) - t[flip]
    lo = lon[over]
    lo[flip] = np.where(lo[flip] <= 0.0, lo[flip] + np.pi, lo[flip] - np.pi)
    lat[over], lon[over] = t, lo


def _chi2(model: Model, x: np.ndarray, data: np.ndarray) -> np.ndarray:
    r = data - model._response_unchecked(x)
    return np.einsum("tn,tn->t", r, r)


def _lm_step(
    model: Model, x: np.ndarray, data: np.ndarray, lam: np.ndarray,
    frozen: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One damped Gauss–Newton proposal; returns (x_new, chi2_old, predicted decrease).

    The response is read off the Jacobian (its intensity columns are the
    unit-intensity responses), so a step costs one Jacobian evaluation.  Fixed
    parameters (an intensity at its bound 0 with the gradient pointing outwards,
    or ``frozen``) get a zero step.  ``x`` (T, P) must be a validated float array.
    """
    jt = model._jacobian_t(x)  # (T, P, N), C-contiguous
    jac = np.swapaxes(jt, 1, 2)  # (T, N, P)
    d1 = model.n_loc + 1
    r = data - (jac[:, :, d1 - 1 :: d1] @ x[:, d1 - 1 :: d1, None])[..., 0]
    a = jt @ jac  # (T, P, P)
    g = (jt @ r[..., None])[..., 0]  # descent direction of chi2 / 2
    t, p = x.shape
    at_bound = (x[:, d1 - 1 :: d1] <= 0.0) & (g[:, d1 - 1 :: d1] <= 0.0)
    diag = a.reshape(t, p * p)[:, :: p + 1]
    floor = damping.EIG_FLOOR * np.maximum(diag.max(axis=1, keepdims=True), 1e-300)
    a_d = a.copy()
    a_d_diag = a_d.reshape(t, p * p)[:, :: p + 1]  # writeable view of the diagonals
    a_d_diag += lam[:, None] * np.maximum(diag, floor)
    if frozen is not None or at_bound.any():
        fixed = np.zeros(x.shape, bool) if frozen is None else np.array(frozen, dtype=bool)
        fixed[:, d1 - 1 :: d1] |= at_bound
        keep = ~fixed
        a_d *= keep[:, :, None] & keep[:, None, :]
        a_d_diag += fixed
        g = np.where(fixed, 0.0, g)
    step = np.linalg.solve(a_d, g[..., None])  # (T, P, 1)
    pred = (2.0 * g - (a @ step)[..., 0])[:, None, :] @ step  # step' (2 g - A step)
    x_new = _project_inplace(model, x + step[..., 0])
    return x_new, np.einsum("tn,tn->t", r, r), pred[:, 0, 0]


def _propose(
    model: Model, x: np.ndarray, data: np.ndarray, lam: np.ndarray, frozen: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_lm_step` and the chi^2 of its proposal, in blocks of trials.

    Every operation is row-wise, so blocking changes no number; it keeps the
    (rows, P, N) intermediates of a large batch in cache (:data:`_BLOCK_TERMS`).
    """
    t, rows = x.shape[0], max(64, _BLOCK_TERMS // max(x.shape[1] * data.shape[1], 1))
    if t <= rows:
        x_new, chi2_old, pred = _lm_step(model, x, data, lam, frozen)
        return x_new, chi2_old, pred, _chi2(model, x_new, data)
    parts = [
        _propose(model, x[i : i + rows], data[i : i + rows], lam[i : i + rows],
                 None if frozen is None else frozen[i : i + rows])
        for i in range(0, t, rows)
    ]
    return tuple(np.concatenate(z) for z in zip(*parts))  # type: ignore[return-value]


def _check_shapes(model: Model, data: np.ndarray, x0: np.ndarray) -> None:
    """data (T, N) and x0 (T, P) with P a multiple of d + 1, else InputError."""
    ds, xs, d1 = np.shape(data), np.shape(x0), model.n_loc + 1
    if len(ds) != 2 or len(xs) != 2 or ds[0] != xs[0] or ds[1] != model.n_sensors or xs[1] % d1:
        raise InputError(
            f"data must have shape (T, {model.n_sensors}) and x0 shape (T, K * {d1}) with "
            f"the same T; got data {ds} and x0 {xs}"
        )


@dataclass(frozen=True)
class Dedupe:
    """Runs that reach an optimum already known for their data stop there.

    The rows of a batch come in groups of ``group`` consecutive runs on the same
    data vector (the starts of one fit).  A run stops, converged, as soon as an
    accepted iterate comes within ``tol`` (max norm, rad and intensity units) of
    its group's row of ``base`` (unless NaN) or of the optimum of an earlier
    converged, unstalled run of the group.  With ``cells`` (rings with the clipped
    cosine only) it also stops on entering the linear cell of such an optimum,
    where chi^2 is convex in the phasors, and reports that optimum.

    Attributes
    ----------
    group : int
        Runs per data vector; the batch size T must be a multiple.
    base : ndarray, shape (T / group, P), or None
        A known optimum per group (NaN rows: none).
    tol : float
        Distance (> 0) within which an iterate counts as the known optimum.
    cells : bool
        Also stop on entering a known optimum's linear cell.
    """

    group: int
    base: np.ndarray | None
    tol: float
    cells: bool = False


def refine_batch(
    model: Model,
    data: np.ndarray,
    x0: np.ndarray,
    *,
    max_iter: int = 300,
    ftol: float = 1e-10,
    frozen: np.ndarray | None = None,
    kinks: bool = False,
    dedupe: Dedupe | None = None,
) -> FitOutcome:
    """Bounded Levenberg–Marquardt from ``x0`` for every row of a batch.

    Compiled (:func:`olsbayes.ml._numba.lm.lm_batch`) when the kernel covers the
    model, else :func:`refine_batch_numpy`; both run the same algorithm (see
    :func:`refine_batch_numpy` for the arguments and the result).

    Parameters
    ----------
    kinks : bool
        Rings and spheres with the clipped cosine: a rejected step that carries a
        source across a sub-sensor's horizon is cut back to the first crossing, and
        a source stuck on a horizon is dealt with there: a ring source's angle is
        frozen; a sphere source moves to the best lower point of a few probes along
        and across the horizon, else slides along its great circle, or has its
        direction frozen where two horizons cross
        (:func:`olsbayes.ml._numba.lm._lm_trial`).  Other
        models have no such horizons in their derivative (their laws are smooth,
        or custom) or are not covered, so the option does not apply to them.
    dedupe : Dedupe, optional
        Stop runs at optima already known for their data (see :class:`Dedupe`).
    """
    from ._numba import lm  # numba is imported on first use, not with the package

    _check_shapes(model, data, x0)
    if dedupe is not None and (dedupe.group < 1 or data.shape[0] % dedupe.group
                               or not dedupe.tol > 0):
        raise InputError(f"dedupe: group must divide the batch of {data.shape[0]} rows and "
                         f"tol be > 0; got group {dedupe.group}, tol {dedupe.tol}")
    if not lm.supports(model):
        return refine_batch_numpy(model, data, x0, max_iter=max_iter, ftol=ftol, frozen=frozen,
                                  dedupe=dedupe)
    x, chi2, conv, nev, stalled = lm.lm_batch(
        model, data, np.asarray(x0, dtype=float), max_iter, ftol, frozen, z_floor(model),
        kinks, dedupe)
    return FitOutcome(x=x, chi2=chi2, converged=conv, n_evaluations=nev, stalled=stalled)


def refine_batch_numpy(
    model: Model,
    data: np.ndarray,
    x0: np.ndarray,
    *,
    max_iter: int = 300,
    ftol: float = 1e-10,
    frozen: np.ndarray | None = None,
    dedupe: Dedupe | None = None,
) -> FitOutcome:
    """Bounded Levenberg–Marquardt from ``x0`` for every row (numpy, lock-step).

    Parameters
    ----------
    model : Model
    data : ndarray, shape (T, N)
    x0 : ndarray, shape (T, P)
        Starting points (projected onto the feasible set first).
    max_iter : int
        Maximum number of LM iterations per run.
    ftol : float
        Stop when an accepted step lowers chi^2 by less than ``ftol * chi^2``
        (plus a floor of 1e-30) or the predicted decrease is below it.
    frozen : ndarray of bool, shape (T, P), optional
        Parameters held at their starting values (e.g. a source pinned on a kink).
    dedupe : Dedupe, optional
        Stop runs at optima already known for their data: the runs of each group
        go one start at a time (all groups in lock-step), so each sees the optima
        of its group's earlier runs, as the compiled kernel's sequential runs do.
        ``dedupe.cells`` concerns rings with the clipped cosine, which always run
        compiled.

    Returns
    -------
    FitOutcome
        ``converged`` is False only for runs that hit ``max_iter``; ``stalled``
        marks runs that stopped because no damped step decreased chi^2 (a
        minimum on a kink of the sensitivity law, or working precision).
    """
    if dedupe is None:
        return _lm_numpy(model, data, x0, max_iter, ftol, frozen, None)
    t, p = np.shape(x0)
    g = dedupe.group
    n_g = t // g
    known = np.zeros((n_g, g + 1, p))
    count = np.zeros(n_g, dtype=np.int64)
    if dedupe.base is not None:
        base = np.asarray(dedupe.base, dtype=float)
        count[:] = ~np.isnan(base[:, 0])
        known[:, 0] = np.where(count[:, None] > 0, base, 0.0)
    parts = []
    for c in range(g):
        rows = np.arange(n_g) * g + c
        fz = None if frozen is None else np.asarray(frozen)[rows]
        out = _lm_numpy(model, data[rows], np.asarray(x0)[rows], max_iter, ftol, fz,
                        (known, count, dedupe.tol))
        seen = _within(out.x, known, count, 0.0)
        add = np.flatnonzero(out.converged & ~out.stalled & ~seen)
        known[add, count[add]] = out.x[add]
        count[add] += 1
        parts.append(out)
    order = np.argsort(np.concatenate([np.arange(n_g) * g + c for c in range(g)]))
    return FitOutcome(*(np.concatenate([getattr(o, f) for o in parts])[order]
                        for f in ("x", "chi2", "converged", "n_evaluations", "stalled")))


def _within(x: np.ndarray, known: np.ndarray, count: np.ndarray, tol: float) -> np.ndarray:
    """Rows of x (n, P) within tol (max norm) of a known row: bool (n,).

    Row i is compared with the first count[i] rows of known[i] (n, J, P).
    """
    valid = np.arange(known.shape[1]) < count[:, None]
    close = np.all(np.abs(x[:, None, :] - known) <= tol, axis=-1)
    return np.any(valid & close, axis=-1)


def _lm_numpy(model: Model, data: np.ndarray, x0: np.ndarray, max_iter: int, ftol: float,
              frozen: np.ndarray | None, stop: tuple | None) -> FitOutcome:
    """Lock-step LM of :func:`refine_batch_numpy`, with an optional stop at known rows.

    ``stop``: (known (T, J, P), count (T,), tol) -- a run whose accepted iterate is
    within tol of a known row stops there.
    """
    x = project(model, x0)
    t = x.shape[0]
    chi2 = np.zeros(t)
    nev = np.full(t, 2 * max_iter, dtype=np.int64)
    done = np.zeros(t, bool)
    stalled = np.zeros(t, bool)
    # Working set of the active runs (rows ``rows`` of the outputs), compacted
    # only when some runs finish: no gather/scatter in the other iterations.
    rows = np.arange(t)
    xa, da, la = x.copy(), data, np.full(t, damping.START)
    fz = frozen
    ka, ca = (None, None) if stop is None else stop[:2]
    for it in range(max_iter):
        if rows.size == 0:
            break
        x_new, chi2_old, pred, chi2_new = _propose(model, xa, da, la, fz)
        tiny = ftol * chi2_old + 1e-30
        acc = chi2_new < chi2_old
        small = (acc & (chi2_old - chi2_new <= tiny)) | (pred <= tiny)
        xa = np.where(acc[:, None], x_new, xa)
        la = np.where(acc, np.maximum(la / damping.DOWN, damping.FLOOR), la * damping.UP)
        near = np.zeros_like(acc) if stop is None else acc & _within(xa, ka, ca, stop[2])
        stall = (la > damping.MAX) & ~small & ~near
        fin = small | stall | near
        if fin.any():
            out = rows[fin]
            x[out] = xa[fin]
            chi2[out] = np.where(acc, chi2_new, chi2_old)[fin]
            nev[out] = 2 * (it + 1)  # one Jacobian (with the response) + one trial response
            done[out] = True
            stalled[out] = stall[fin]
            keep = ~fin
            rows, xa, da, la = rows[keep], xa[keep], da[keep], la[keep]
            fz = None if fz is None else fz[keep]
            if stop is not None:
                ka, ca = ka[keep], ca[keep]
    if rows.size:  # hit max_iter
        x[rows] = xa
        chi2[rows] = _chi2(model, xa, da)
    return FitOutcome(x=x, chi2=chi2, converged=done, n_evaluations=nev, stalled=stalled)
