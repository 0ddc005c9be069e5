"""Local stages of the fast fit: LM from many starts, restarts, kink hops, kink polish.

Each stage refines a set of starts per data vector in one batched
Levenberg–Marquardt run (:func:`olsbayes.ml.lm.refine_batch`) and keeps, per
data vector, the best optimum so far.  The likelihood of the clipped cosine is
smooth only between the angles at which a source crosses a sub-sensor's 90 deg
horizon (its *kinks*); the restarts, hops and the polish are there to leave the
shallow false minima that these kinks create.
"""

from __future__ import annotations

import functools

import numpy as np

from ...circular import wrap_angle
from ...model import Model
from ...sensitivity import is_clipped_cosine
from ..lm import Dedupe, refine_batch
from ..outcome import FitOutcome
from .options import FastOptions

__all__ = ["refine_starts", "restart", "restart_patterns", "hop_starts", "kink_hops",
           "kink_polish"]


def refine_starts(
    model: Model, data: np.ndarray, starts: np.ndarray, opts: FastOptions,
    known: np.ndarray | None = None, keep: bool = False,
) -> FitOutcome:
    """One batched LM run over starts (T, C, K, d+1); the best chi^2 per data vector wins.

    Runs reaching an optimum already found for their data vector (``known`` (T, P),
    NaN rows: none, or an earlier start's) stop there (``opts.dedupe_tol``).
    ``keep``: every converged run's optimum goes to ``alternatives``.
    """
    t, c = starts.shape[:2]
    if known is None:
        known = np.full((t, starts.shape[2] * starts.shape[3]), np.nan)
    dedupe = (Dedupe(group=c, base=known, tol=opts.dedupe_tol, cells=opts.cell_stop)
              if opts.dedupe_tol > 0 else None)
    cand = refine_batch(model, np.repeat(data, c, axis=0), starts.reshape(t * c, -1),
                        max_iter=opts.max_iter, kinks=opts.kink_cuts and model.kind == "angle",
                        dedupe=dedupe)
    pick = np.arange(t) * c + np.argmin(cand.chi2.reshape(t, c), axis=1)
    out = cand.take(pick)
    alt = None
    if keep:
        alt = (cand.x.reshape(t, c, -1),
               np.where(cand.converged, cand.chi2, np.inf).reshape(t, c))
    return FitOutcome(out.x, out.chi2, out.converged,
                      cand.n_evaluations.reshape(t, c).sum(axis=1), out.stalled, alt)


def _known(out: FitOutcome) -> np.ndarray:
    """Fits that converged without stalling (else NaN rows): known optima, (T, P)."""
    return np.where((out.converged & ~out.stalled)[:, None], out.x, np.nan)


def _improves(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Where a chi^2 ``new`` beats ``old`` by more than rounding (what :func:`_merge` keeps)."""
    return new < old * (1 - 1e-12)


def _merge(out: FitOutcome, rows: np.ndarray, new: FitOutcome) -> FitOutcome:
    """Replace the fits ``rows`` of ``out`` by ``new`` where it is strictly better."""
    x, chi2 = out.x.copy(), out.chi2.copy()
    conv, nev, stalled = out.converged.copy(), out.n_evaluations.copy(), out.stalled.copy()
    nev[rows] += new.n_evaluations
    better = _improves(new.chi2, chi2[rows])
    sel = rows[better]
    x[sel], chi2[sel], conv[sel] = new.x[better], new.chi2[better], new.converged[better]
    stalled[sel] = new.stalled[better]
    return FitOutcome(x, chi2, conv, nev, stalled)


def _kinked(model: Model, x: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """:func:`~olsbayes.bounds.kink_sources` of fits x (T, P), compiled: bool (T, K)."""
    if not model.sensitivity.kink:
        return np.zeros((x.shape[0], x.shape[1] // (model.n_loc + 1)), bool)
    from .._numba import refine  # numba is imported on first use

    return refine.on_kink(model, x, atol)


def restart_patterns(k: int, d: int, n: int) -> np.ndarray:
    """``n`` deterministic sign patterns for the restarts, shape (n, K, d).

    The first four are all +1, all -1, alternating +-, alternating -+ (over the
    flattened K*d location coordinates); further ones cycle through a fixed
    Hadamard-like sequence.
    """
    m = k * d
    j = np.arange(m)
    base = [np.ones(m), -np.ones(m), (-1.0) ** j, -((-1.0) ** j)]
    extra = 0
    while len(base) < n:
        extra += 1
        base.append(np.where(((j + 1) >> (extra - 1)) & 1, 1.0, -1.0) * (-1.0) ** extra)
    return np.array(base[:n]).reshape(n, k, d)


@functools.lru_cache(maxsize=64)
def _patterns(k: int, d: int, n: int) -> np.ndarray:
    """:func:`restart_patterns`, read-only and memoised (every fit of a K uses the same)."""
    out = restart_patterns(k, d, n)
    out.flags.writeable = False
    return out


def restart(model: Model, data: np.ndarray, out: FitOutcome, delta: np.ndarray,
            opts: FastOptions) -> FitOutcome:
    """Perturbed restarts around the refined optima, all patterns in one LM run.

    Every source location is shifted by the fixed sign patterns of
    :func:`restart_patterns` times ``delta`` (d,).  They reach the neighbouring
    basins of the false minima near a kink.  Every fit for K >= 3; for K <= 2
    only fits that stalled or ended with a source on a kink.
    """
    d = model.n_loc
    k = out.x.shape[1] // (d + 1)
    patterns = _patterns(k, d, opts.n_restarts)
    rows = np.arange(out.x.shape[0])
    if k <= 2:
        rows = np.flatnonzero(out.stalled | np.any(_kinked(model, out.x), axis=-1))
    if rows.size == 0:
        return out
    base = out.x[rows].reshape(rows.size, 1, k, d + 1)
    starts = np.repeat(base, patterns.shape[0], axis=1)
    starts[..., :d] += patterns * delta
    return _merge(out, rows, refine_starts(model, data[rows], starts, opts,
                                           _known(out.take(rows))))


def hop_starts(model: Model, x: np.ndarray) -> np.ndarray:
    """Kink hops of fits x (T, P) of a planar (angle) model: starts (T, 2K, P).

    Start 2j (2j + 1) moves source j's angle up (down) just past the nearest
    angle at which some sub-sensor sits on the source's 90 deg horizon, i.e. into
    the neighbouring cell where the likelihood is a different smooth function.
    The numpy statement of :func:`olsbayes.ml._numba.refine.hop_starts`.
    """
    k = x.shape[1] // 2
    nrm = model.array.normals
    phi = np.arctan2(nrm[:, 1], nrm[:, 0])
    crossings = np.concatenate([phi + np.pi / 2, phi - np.pi / 2])  # (2N,)
    diff = wrap_angle(crossings - x[:, 0::2, None])  # (T, K, 2N)
    up = np.where(diff > 1e-9, diff, np.inf).min(axis=-1)  # (T, K)
    down = np.where(diff < -1e-9, diff, -np.inf).max(axis=-1)
    eps = 0.05 * np.pi / model.n_sensors  # 5 % of the mean gap between crossings
    starts = np.repeat(x[:, None, :], 2 * k, axis=1)
    j = np.arange(k)
    starts[:, 2 * j, 2 * j] += up + eps
    starts[:, 2 * j + 1, 2 * j] += down - eps
    return starts


def kink_hops(model: Model, data: np.ndarray, out: FitOutcome,
              opts: FastOptions) -> FitOutcome:
    """One round of kink hops for every fit, all 2K hops per fit in one LM run.

    With several sources the likelihood has shallow local minima in neighbouring
    smooth cells about one CRLB std apart, which the fixed-size restarts step over.
    """
    from .._numba import refine  # numba is imported on first use

    t, k = out.x.shape[0], out.x.shape[1] // 2
    starts = refine.hop_starts(model, out.x).reshape(t, 2 * k, k, 2)  # == hop_starts
    return _merge(out, np.arange(t), refine_starts(model, data, starts, opts, _known(out)))


def kink_polish(model: Model, data: np.ndarray, out: FitOutcome,
                opts: FastOptions) -> FitOutcome:
    """Re-optimise fits with a source pinned on a kink.

    At a kink the one-sided Jacobian misleads LM, which then stops with the
    remaining parameters not quite optimal.  On a ring (or plate) holding the
    kinked source's location fixed makes the rest a smooth problem.  A sphere
    source on a horizon may still slide along its great circle, so there (with
    ``kink_cuts``) every fit is refined by LM holding sources on the horizons they
    reach, twice, since a source held (or frozen where two horizons cross) for
    the rest of one run may leave it in the next (``kinks``,
    :func:`olsbayes.ml._numba.lm._lm_trial`).  A fit is replaced only where this
    improves its chi^2.
    """
    if not model.sensitivity.kink:
        return out
    if opts.kink_cuts and model.kind == "lonlat" and is_clipped_cosine(model.sensitivity):
        rows = np.arange(out.x.shape[0])
        for _ in range(2):  # the second run may leave horizons the first held
            if rows.size == 0:
                break
            new = refine_batch(model, data[rows], out.x[rows], max_iter=opts.max_iter,
                               kinks=True)
            moved = rows[_improves(new.chi2, out.chi2[rows])]
            out = _merge(out, rows, new)
            rows = moved  # a run from an unchanged fit would repeat the first
        return out
    kinked = _kinked(model, out.x, atol=1e-6)  # (T, K)
    rows = np.flatnonzero(kinked.any(axis=1))
    if rows.size == 0:
        return out
    d1 = model.n_loc + 1
    frozen = np.repeat(kinked[rows], d1, axis=1)
    frozen[:, d1 - 1 :: d1] = False  # intensities stay free
    new = refine_batch(model, data[rows], out.x[rows], max_iter=opts.max_iter, frozen=frozen)
    x, chi2, nev = out.x.copy(), out.chi2.copy(), out.n_evaluations.copy()
    nev[rows] += new.n_evaluations
    better = new.chi2 < chi2[rows]
    x[rows[better]], chi2[rows[better]] = new.x[better], new.chi2[better]
    return FitOutcome(x, chi2, out.converged, nev, out.stalled)
