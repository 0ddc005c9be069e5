"""Batched, bounded Levenberg–Marquardt refinement of Eq. 2 over many trials.

All trials advance in lock-step with numpy broadcasting over a leading trial
axis: one call of ``model.response`` / ``model.jacobian`` on a (T, P) array per
iteration, a batched (T, P, P) solve, and per-trial damping.  Trials that have
met the stopping rule drop out of the active set, so the cost follows the
slowest trial only in iterations, not in work.

Bounds: intensities >= 0 (active set: an intensity at 0 whose gradient points
outwards is frozen for that step), latitudes in [-pi/2, pi/2], plate z > 0.

:func:`refine_batch` runs the same algorithm compiled, one trial at a time
(:mod:`olsbayes.ml._kernel`), for the models the kernel covers (ring, sphere
and plate with the clipped cosine or cos^p laws) -- for a few candidates of a
small model numpy's per-call overhead dominates the lock-step version.  The
numpy version :func:`refine_batch_numpy` is the reference and serves other laws.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..model import Model

__all__ = ["LMOutcome", "project", "refine_batch", "refine_batch_numpy"]

#: Damping above which no descent step is representable: the point is a local
#: minimum to working precision (e.g. sitting on the kink of the clipped cosine).
_LAMBDA_MAX = 1e14

#: Jacobian entries (trials x P x N) per block of an LM iteration on a large
#: batch (see :func:`_propose`): ~1 MiB, so the intermediates stay in cache.
#: Measured on a 30-ring, K = 2, 16000 candidates: 158 ms unblocked, 109-112 ms
#: for blocks of 512-2048 trials.
_BLOCK_TERMS = 131072


@dataclass(frozen=True)
class LMOutcome:
    """Result of :func:`refine_batch` (internal)."""

    x: np.ndarray  # (T, P)
    chi2: np.ndarray  # (T,) sum of squared residuals (not divided by sigma^2)
    converged: np.ndarray  # (T,) bool
    n_evaluations: np.ndarray  # (T,) int
    stalled: np.ndarray | None = None  # (T,) bool, stopped with no descent step
    # other optima the method reached per trial: x (T, C, P), chi2 (T, C) (inf: none)
    alternatives: tuple[np.ndarray, np.ndarray] | None = None


def _z_floor(model: Model) -> float:
    pos = model.array.positions
    scale = float(np.ptp(pos[:, :2])) if pos is not None else 1.0
    return 1e-6 * max(scale, 1e-12)


def project(model: Model, x: np.ndarray) -> np.ndarray:
    """Map parameters onto the feasible set (intensity >= 0, |lat| <= pi/2, z > 0)."""
    return _project_inplace(model, np.array(x, dtype=float))


def _project_inplace(model: Model, x: np.ndarray) -> np.ndarray:
    d1 = model.n_loc + 1
    np.maximum(x[..., d1 - 1 :: d1], 0.0, out=x[..., d1 - 1 :: d1])
    if model.kind == "lonlat":
        x[..., 1::d1] = np.clip(x[..., 1::d1], -np.pi / 2, np.pi / 2)
    elif model.kind == "position":
        x[..., 2::d1] = np.maximum(x[..., 2::d1], _z_floor(model))
    return x


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
    floor = 1e-9 * np.maximum(diag.max(axis=1, keepdims=True), 1e-300)
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


def refine_batch(
    model: Model,
    data: np.ndarray,
    x0: np.ndarray,
    *,
    max_iter: int = 300,
    ftol: float = 1e-10,
    frozen: np.ndarray | None = None,
    kinks: bool = False,
    group: int = 1,
    known: np.ndarray | None = None,
    dedupe_tol: float = 0.0,
) -> LMOutcome:
    """Bounded Levenberg–Marquardt from ``x0`` for every trial.

    Compiled (:func:`olsbayes.ml._kernel.lm_batch`) when the kernel covers the
    model, else :func:`refine_batch_numpy`; both run the same algorithm and
    take and return the same (see :func:`refine_batch_numpy`).  ``kinks``
    (compiled path, ring with the clipped cosine): rejected steps are cut back
    to the first sub-sensor horizon they cross, and a source stuck on one has
    its angle held (see :func:`olsbayes.ml._kernel._lm_trial`).  ``group``,
    ``known`` (T / group, P; NaN rows: none), ``dedupe_tol`` > 0 (compiled
    path): a run stops where it comes within dedupe_tol of the known optimum of
    its group of ``group`` consecutive rows or of an earlier converged run of
    the group (see :func:`olsbayes.ml._kernel._lm_all`).
    """
    from . import _kernel  # numba is imported on first use, not with the package

    _check_shapes(model, data, x0)
    if not _kernel.supports(model):
        return refine_batch_numpy(model, data, x0, max_iter=max_iter, ftol=ftol, frozen=frozen)
    x, chi2, conv, nev, stalled = _kernel.lm_batch(
        model, data, np.asarray(x0, dtype=float), max_iter, ftol, frozen, _z_floor(model),
        kinks, group, known, dedupe_tol)
    return LMOutcome(x=x, chi2=chi2, converged=conv, n_evaluations=nev, stalled=stalled)


def refine_batch_numpy(
    model: Model,
    data: np.ndarray,
    x0: np.ndarray,
    *,
    max_iter: int = 300,
    ftol: float = 1e-10,
    frozen: np.ndarray | None = None,
) -> LMOutcome:
    """Bounded Levenberg–Marquardt from ``x0`` for every trial at once (numpy).

    Parameters
    ----------
    model : Model
    data : ndarray, shape (T, N)
    x0 : ndarray, shape (T, P)
        Starting points (projected onto the feasible set first).
    max_iter : int
        Maximum number of LM iterations per trial.
    ftol : float
        Stop when an accepted step lowers chi^2 by less than ``ftol * chi^2``
        (plus a floor of 1e-30) or the predicted decrease is below it.
    frozen : ndarray of bool, shape (T, P), optional
        Parameters held at their starting values (e.g. a source pinned on a kink).

    Returns
    -------
    LMOutcome
        ``converged`` is False only for trials that hit ``max_iter``; ``stalled``
        marks trials that stopped because no damped step decreased chi^2 (a
        minimum on a kink of the sensitivity law, or working precision).
    """
    x = project(model, x0)
    t = x.shape[0]
    chi2 = np.zeros(t)
    nev = np.full(t, 2 * max_iter, dtype=np.int64)
    done = np.zeros(t, bool)
    stalled = np.zeros(t, bool)
    # Working set of the active trials (rows ``rows`` of the outputs), compacted
    # only when some trials finish: no gather/scatter in the other iterations.
    rows = np.arange(t)
    xa, da, la = x.copy(), data, np.full(t, 1e-3)
    fz = frozen
    for it in range(max_iter):
        if rows.size == 0:
            break
        x_new, chi2_old, pred, chi2_new = _propose(model, xa, da, la, fz)
        tiny = ftol * chi2_old + 1e-30
        acc = chi2_new < chi2_old
        small = (acc & (chi2_old - chi2_new <= tiny)) | (pred <= tiny)
        xa = np.where(acc[:, None], x_new, xa)
        la = np.where(acc, np.maximum(la / 5.0, 1e-12), la * 8.0)
        stall = (la > _LAMBDA_MAX) & ~small
        fin = small | stall
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
    if rows.size:  # hit max_iter
        x[rows] = xa
        chi2[rows] = _chi2(model, xa, da)
    return LMOutcome(x=x, chi2=chi2, converged=done, n_evaluations=nev, stalled=stalled)
