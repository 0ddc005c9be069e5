"""Scattered starts: many fixed, spread-out configurations refined by LM (K >= 5).

From five sources on, the likelihood of the clipped cosine has many optima of
nearly equal height that differ in several sources at once (per-arc sinusoids
pin down sums of phasors, not the phasors), and neither the grid search nor
moves of one or two sources from its best fit reach the others reliably.  A
batch of ``n`` configurations spread over the whole source space, each with
its least-squares intensities and refined by the compiled LM, does -- as the
paper's multistart baseline, but with compiled LM runs that stop at optima
already found (``dedupe_tol``).

The configurations come from a fixed seed, the same for every data vector, so
the fit stays deterministic and a batch equals a loop of single fits.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...model import Model
from ..outcome import FitOutcome
from .options import FastOptions
from .refine import _known, _merge, refine_starts

__all__ = ["scatter_locations", "scattered"]

#: Seed of the scattered configurations (fixed: the fast fit is deterministic).
SEED = 20250611


def scatter_locations(model: Model, k: int, n: int, grid: np.ndarray) -> np.ndarray:
    """``n`` fixed configurations of K source locations, shape (n, K, d).

    Ring angles uniform on the circle, sphere directions uniform on the sphere,
    plate positions uniform in the box of the grid of candidate locations.
    """
    gen = np.random.default_rng(SEED)
    if model.kind == "angle":
        return gen.uniform(-np.pi, np.pi, (n, k, 1))
    if model.kind == "lonlat":
        lon = gen.uniform(-np.pi, np.pi, (n, k))
        return np.stack([lon, np.arcsin(gen.uniform(-1.0, 1.0, (n, k)))], axis=-1)
    return gen.uniform(grid.min(axis=0), grid.max(axis=0), (n, k, 3))


def _starts(model: Model, data: np.ndarray, loc: np.ndarray) -> np.ndarray:
    """Starts (T, n, K, d+1): the locations with each data vector's LS intensities (>= 0)."""
    n, k, d = loc.shape
    unit = np.concatenate([loc, np.ones((n, k, 1))], axis=-1).reshape(n * k, d + 1)
    a = model.response(unit).reshape(n, k, -1)  # (n, K, N) unit responses
    gram = a @ a.swapaxes(1, 2) + 1e-12 * np.eye(k) * np.trace(a @ a.swapaxes(1, 2),
                                                                axis1=1, axis2=2)[:, None, None]
    proj = np.linalg.solve(gram, a)  # (n, K, N): least-squares intensities = proj @ s
    inten = np.maximum(np.einsum("ckn,tn->tck", proj, data), 0.0)
    loc_t = np.broadcast_to(loc, (data.shape[0],) + loc.shape)
    return np.concatenate([loc_t, inten[..., None]], axis=-1)


def scattered(model: Model, data: np.ndarray, out: FitOutcome, grid: np.ndarray,
              opts: FastOptions) -> FitOutcome:
    """``opts.scatter`` scattered starts per data vector in one LM run; the better fits win.

    The optima of the runs, (T, n, P) with their chi^2 (T, n) (inf where a run did
    not converge), go to ``alternatives`` of the result (the sliding search's
    starts and the rival check's candidates).
    """
    k = out.x.shape[1] // (model.n_loc + 1)
    loc = scatter_locations(model, k, opts.scatter, grid)
    starts = _starts(model, data, loc)
    rows = np.arange(data.shape[0])
    new = refine_starts(model, data, starts, opts, _known(out), keep=True)
    return dataclasses.replace(_merge(out, rows, new), alternatives=new.alternatives)
