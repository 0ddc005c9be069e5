"""Sliding local search over source sets: relocate one or two sources, refine, repeat.

From five sources on, the likelihood of the clipped cosine has many optima of
nearly equal height that differ in one or several sources (per-arc sinusoids pin
down sums of phasors, not the phasors), and a joint refinement from the grid
search's candidates or from scattered starts often stops in one of them.  The
moves of the alternating descent used for sparse spike deconvolution leave such
an optimum: take one source out, or two one after the other, and place each
again at the grid atom best correlated with the residual of the others --
outside the basins of the current sources, so that every move explores -- solve all
intensities by least squares and refine all sources jointly by bounded
Levenberg–Marquardt.  The best move of a sweep is kept if it lowers chi^2, and
the sweeps go on until none does (at most ``slide_sweeps``).

The search starts from the ``slide`` best distinct optima found before (the
search candidates', the scattered starts', the current fit), since the moves of
one or two sources do not connect every pair of optima.  A path stops when it
reaches an optimum that another path of its data vector has visited: from there
both would go on alike.

Cost per sweep and start: K (K + 1) / 2 LM runs of all 2K or 3K parameters and
O(K M N) for the correlations of the residual and of the current sources with
the M atoms (the moves update them through the atoms' Gram matrix), so the
search is polynomial in K.  All moves of all data vectors run in one batched LM
call per sweep; being deterministic, a batch equals a loop of single fits.
"""

from __future__ import annotations

import itertools

import numpy as np

from ...model import Model
from ..atoms import NEIGHBOUR
from ..outcome import FitOutcome
from .options import FastOptions
from .refine import _improves, _known, refine_starts
from .search import _atom_views, model_views

__all__ = ["slide", "relocations", "distinct_best"]


def distinct_best(chi2: np.ndarray, n: int, rtol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the ``n`` lowest distinct finite values in each row of chi2 (T, C).

    Values within ``rtol`` (relative) of the next lower one count as one optimum.
    Returns (rows, cols), row-major, up to n entries per row.
    """
    order = np.argsort(chi2, axis=1, kind="stable")
    v = np.take_along_axis(chi2, order, axis=1)
    new = np.isfinite(v)
    new[:, 1:] &= v[:, 1:] > v[:, :-1] * (1 + rtol) + 1e-300
    rank = np.cumsum(new, axis=1) - 1
    rows, pos = np.nonzero(new & (rank < n))
    return rows, order[rows, pos]


def _moves(k: int) -> list[tuple[int, ...]]:
    """The source sets a sweep relocates: every single source, then every pair."""
    return [(i,) for i in range(k)] + list(itertools.combinations(range(k), 2))


def _ls_intensities(model: Model, loc: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Least-squares intensities (R, K) >= 0 of sources at loc (R, K, d) for data (R, N)."""
    r, k, _ = loc.shape
    x = np.concatenate([loc, np.ones((r, k, 1))], axis=-1).reshape(r * k, -1)
    a = model._response_unchecked(x).reshape(r, k, -1)
    gram = a @ a.swapaxes(1, 2)
    gram += 1e-12 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(k)
    return np.maximum(np.linalg.solve(gram, a @ data[:, :, None])[..., 0], 0.0)


def relocations(model: Model, g: np.ndarray, grid: np.ndarray, data: np.ndarray,
                x: np.ndarray) -> np.ndarray:
    """Starts (T, C, K, d+1) of every move of one sweep from fits x (T, P) of data (T, N).

    Move c takes the sources ``_moves(K)[c]`` out one by one and places each again
    at the atom (rows of g (M, N), locations ``grid`` (M, d)) of largest positive
    normalised correlation with the residual of all other sources (those not yet
    moved at their old places, those moved at their new ones), excluding the
    basins (normalised correlation > :data:`~olsbayes.ml.atoms.NEIGHBOUR`) of every
    current source and of the atoms placed before; the intensities of all sources
    are then solved by least squares (clipped at 0).
    """
    gv, gram, gnorm2 = _atom_views(g, model_views(model, g, grid)[0])[:3]
    t, d1 = x.shape[0], model.n_loc + 1
    k = x.shape[1] // d1
    blocks = x.reshape(t, k, d1)
    inv = 1.0 / np.sqrt(np.maximum(gnorm2, 1e-300))
    unit_x = np.concatenate([blocks[..., :-1], np.ones((t, k, 1))], axis=-1)
    a = model._response_unchecked(unit_x.reshape(t * k, d1)).reshape(t, k, -1)
    a_g = a @ gv.T  # (T, K, M): correlations of the current sources with the atoms
    a_inv = 1.0 / np.maximum(np.linalg.norm(a, axis=-1), 1e-300)
    banned0 = np.any(a_g * a_inv[..., None] * inv > NEIGHBOUR, axis=1)  # (T, M)
    c0 = (data - model._response_unchecked(x)) @ gv.T  # (T, M)
    moves = _moves(k)
    starts = np.repeat(blocks[:, None], len(moves), axis=1)
    rows = np.arange(t)
    for c, move in enumerate(moves):
        corr = c0.copy()
        banned = banned0.copy()
        for j in move:  # source j leaves; the sources not yet moved stay where they are
            corr += blocks[:, j, -1, None] * a_g[:, j]
            best = np.argmax(np.where(banned, -np.inf, corr * inv), axis=1)
            w = np.maximum(corr[rows, best], 0.0) * inv[best] ** 2
            starts[:, c, j, :-1] = grid[best]
            grow = gram[best] if gram.size else gv[best] @ gv.T  # (T, M)
            corr = corr - w[:, None] * grow
            banned |= grow * inv[best, None] * inv > NEIGHBOUR
    loc = starts[..., :-1].reshape(t * len(moves), k, d1 - 1)
    inten = _ls_intensities(model, loc, np.repeat(data, len(moves), axis=0))
    starts[..., -1] = inten.reshape(t, len(moves), k)
    return starts


def _first_visits(owner: np.ndarray, chi2: np.ndarray, seen_owner: np.ndarray,
                  seen_chi2: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Mask of the entries (owner, chi2) that no earlier entry of the same owner matches.

    An entry matches an optimum already visited (``seen_*``) or an earlier entry of
    the batch if their chi^2 agree to ``rtol`` (relative): one optimum.
    """
    o = np.concatenate([seen_owner, owner])
    c = np.concatenate([seen_chi2, chi2])
    new = np.arange(o.size) >= seen_owner.size
    order = np.lexsort((~new, c, o))  # by owner, then chi^2; visited first among ties
    os_, cs = o[order], c[order]
    dup = np.zeros(o.size, bool)
    dup[1:] = (os_[1:] == os_[:-1]) & (cs[1:] <= cs[:-1] * (1 + rtol) + 1e-300)
    keep = np.empty(o.size, bool)
    keep[order] = ~dup
    return keep[new]


def _sweeps(model: Model, data: np.ndarray, owner: np.ndarray, out: FitOutcome, g: np.ndarray,
            grid: np.ndarray, opts: FastOptions) -> FitOutcome:
    """Relocation sweeps from every fit of ``out`` (of data (R, N)) until none improves.

    ``owner`` (R,): the data vector of each row.  A row stops when its sweep
    reaches an optimum that a row of the same owner has visited (or reaches in the
    same sweep): from there both would take the same path.
    """
    x, chi2, nev = out.x.copy(), out.chi2.copy(), out.n_evaluations.copy()
    conv, stalled = out.converged.copy(), out.stalled.copy()
    live = np.arange(x.shape[0])
    seen_owner, seen_chi2 = owner.copy(), chi2.copy()
    for _ in range(opts.slide_sweeps):
        if live.size == 0:
            break
        cur = FitOutcome(x[live], chi2[live], conv[live], nev[live], stalled[live])
        new = refine_starts(model, data[live], relocations(model, g, grid, data[live], x[live]),
                            opts, _known(cur))
        nev[live] += new.n_evaluations
        better = new.chi2 < chi2[live] * (1 - 1e-9)
        sel = live[better]
        x[sel], chi2[sel], conv[sel] = new.x[better], new.chi2[better], new.converged[better]
        stalled[sel] = new.stalled[better]
        fresh = _first_visits(owner[sel], chi2[sel], seen_owner, seen_chi2)
        seen_owner = np.concatenate([seen_owner, owner[sel]])
        seen_chi2 = np.concatenate([seen_chi2, chi2[sel]])
        live = sel[fresh]
    return FitOutcome(x, chi2, conv, nev, stalled)


def slide(model: Model, data: np.ndarray, out: FitOutcome, pool: tuple[np.ndarray, np.ndarray],
          g: np.ndarray, grid: np.ndarray, opts: FastOptions) -> FitOutcome:
    """The sliding search from the ``opts.slide`` best distinct optima per data vector.

    ``out``: the current fits of data (T, N); ``pool``: other optima found for them,
    (T, C, P) with their chi^2 (T, C) (inf: none).  Returns ``out`` with each fit
    replaced by the best optimum the search reached where that is better.
    """
    t = data.shape[0]
    xs = np.concatenate([out.x[:, None], pool[0]], axis=1)
    cs = np.concatenate([out.chi2[:, None], pool[1]], axis=1)
    owner, col = distinct_best(cs, opts.slide)
    n = owner.size
    start = FitOutcome(xs[owner, col], cs[owner, col], np.ones(n, bool),
                       np.zeros(n, np.int64), np.zeros(n, bool))
    res = _sweeps(model, data[owner], owner, start, g, grid, opts)
    # every data vector has >= 1 start (its fit): the first of its rows by chi^2
    best = np.lexsort((res.chi2, owner))[np.searchsorted(owner, np.arange(t))]
    x, chi2 = out.x.copy(), out.chi2.copy()
    conv, stalled = out.converged.copy(), out.stalled.copy()
    nev = out.n_evaluations + np.bincount(owner, weights=res.n_evaluations,
                                          minlength=t).astype(np.int64)
    better = _improves(res.chi2[best], chi2)
    sel, src = np.flatnonzero(better), best[better]
    x[sel], chi2[sel], conv[sel], stalled[sel] = (res.x[src], res.chi2[src], res.converged[src],
                                                  res.stalled[src])
    return FitOutcome(x, chi2, conv, nev, stalled)
