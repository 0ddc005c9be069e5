"""The cells of the ring quadrature: a coarse screen, then fine cells where the mass is.

The direction integral of :func:`~olsbayes.select.quadrature.ring_log_evidence`
runs over the circle (K = 1) or the torus (K = 2).  Coarse cells are screened
by the unconstrained best fit at their centre (:func:`projection_gain`, an
upper bound of the likelihood over the intensities) with a slack for the
likelihood's curvature across a cell, and the kept ones are split into fine
cells, kept on the same rule.

Square fine cells of about one posterior width (:func:`screen`) suit a
posterior that is narrow in every direction.  Two sources whose second one
adds little to one are not: one direction sits near the fit, the other,
carrying an intensity near zero, anywhere on the circle.  The mass then lies
on two full-circle arms, narrow across and flat along, one per labelling, and
square cells of the narrowest width cannot cover them within the budget.
:func:`aligned_cells` then sizes each coarse cell's split per direction from
the local curvature of the log-likelihood, ``I_j^2 |dg/dtheta_j|^2 / sigma^2``
at the cell's centre (the Gauss-Newton curvature along ``theta_j`` with the
intensities at their best): fine along the arm's narrow direction, whole
along the flat one.  The estimate stays unbiased whatever the cells' shape
(uniform draws in each cell); only its stated error depends on the split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._budget import memory_limit

__all__ = ["Cells", "cell_budget", "screen", "aligned_cells", "unit_responses", "projection_gain"]

_SAFETY = 4.0       # curvature slack of the coarse screen, in units of its quadratic estimate
_COARSE = 8.0       # coarse cell width in narrowest posterior widths
_FINE = (0.25, 2.0)  # fine cell width in narrowest posterior widths, K = 1 and 2
_WIDEST = 8.0       # the widest fine cells, in narrowest posterior widths, within budget
_WIDEST_ALIGNED = 32.0  # the same for cells aligned with the likelihood (the error decides)
_BYTES_PER_CELL = 8.0 * 20
_MAX_CELLS = 2**20   # cells per level (beyond: a cost out of proportion; nested sampling)
_MAX_DRAWN = 2**17   # fine cells that get draws (beyond: wider fine cells)
_CHUNK = 2**15       # draws evaluated at once (their responses: _CHUNK x K x N floats)
_STEP = 1e-6        # rad, central-difference step of the responses' slope


@dataclass(frozen=True)
class Cells:
    """Fine cells of the direction grid.

    Cell ``c`` spans ``-pi + width[c, j] * (index[c, j] + [0, 1])`` in direction ``j``.

    Attributes
    ----------
    index : ndarray of int, shape (m, K)
    width : ndarray, shape (m, K)
        rad; every entry equal for square cells.
    n_grid : int
        Cells per direction on the full circle at the finest width.
    """

    index: np.ndarray
    width: np.ndarray
    n_grid: int

    def __repr__(self) -> str:
        return f"Cells(m={len(self.index)}, K={self.index.shape[1]}, n_grid={self.n_grid})"

    def draw(self, per_cell: int, rng: np.random.Generator) -> np.ndarray:
        """``per_cell`` uniform directions (m * per_cell, K) in each cell, cell by cell."""
        rep = np.repeat(self.index, per_cell, axis=0)
        return -math.pi + np.repeat(self.width, per_cell, axis=0) * (
            rep + rng.uniform(size=rep.shape))

    def log_area(self) -> tuple[np.ndarray, float]:
        """Each cell's area relative to the largest (m,), and log of the largest / (2 pi)^K."""
        ref = self.width.max(axis=0)
        rel = np.prod(self.width / ref, axis=1)
        return rel, float(sum(math.log(w / (2 * math.pi)) for w in ref))


def unit_responses(model, theta: np.ndarray) -> np.ndarray:
    """Readings (n, N) of unit-intensity ring sources at angles ``theta`` (n,) rad."""
    return model.response(np.stack([theta, np.ones_like(theta)], axis=-1))


def projection_gain(gd_i: np.ndarray, gd_j: np.ndarray | None, a: np.ndarray,
                    c: np.ndarray | None = None, b: np.ndarray | None = None) -> np.ndarray:
    """|projection of the readings on span(g_i[, g_j])|^2, the unconstrained best fit.

    ``gd = g . y``; ``a = |g_i|^2``, ``c = |g_j|^2``, ``b = g_i . g_j`` (broadcast).
    One direction when ``gd_j`` is None; two coincident directions (Gram matrix
    singular to rounding) count as one.  ``(|y|^2 - gain) / 2 sigma^2`` is then the
    smallest misfit over all intensities (an upper bound of the log-likelihood).
    """
    single_i = gd_i**2 / a
    if gd_j is None:
        return single_i
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (c * gd_i**2 - 2 * b * gd_i * gd_j + a * gd_j**2) / det
    return np.where(det > 1e-12 * a * c, q, np.maximum(single_i, gd_j**2 / c))


def _pair_terms(g: np.ndarray, data: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, ...]:
    """``g_i . y, g_j . y, |g_i|^2, |g_j|^2, g_i . g_j`` (each (m,)) of the pairs ``idx`` (m, 2).

    ``g`` (u, N): the responses the pairs index into; ``g_i . g_j`` in passes of
    bounded memory.
    """
    gd, a = g @ data, np.einsum("ij,ij->i", g, g)
    i, j = idx[:, 0], idx[:, 1]
    b = np.concatenate([np.einsum("ms,ms->m", g[i[c:c + _CHUNK]], g[j[c:c + _CHUNK]])
                        for c in range(0, len(i), _CHUNK)])
    return gd[i], gd[j], a[i], a[j], b


def _pair_solve(gi: np.ndarray, gj: np.ndarray, ai: np.ndarray, aj: np.ndarray,
                b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unconstrained best intensities (x_i, x_j) of two directions, and where they are defined.

    The 2 x 2 normal equations ``[[ai, b], [b, aj]] x = (gi, gj)`` by Cramer's rule;
    the third output is False where the Gram matrix is singular to rounding (the
    intensities there are not meaningful).
    """
    det = ai * aj - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        xi, xj = (aj * gi - b * gj) / det, (ai * gj - b * gi) / det
    return xi, xj, det > 1e-12 * ai * aj


def _pair_gains(g: np.ndarray, data: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Best-fit gain of the direction tuples ``idx`` (m, K) into the responses ``g`` (u, N)."""
    if idx.shape[1] == 1:
        gd, a = g @ data, np.einsum("ij,ij->i", g, g)
        return projection_gain(gd[idx[:, 0]], None, a[idx[:, 0]])
    return projection_gain(*_pair_terms(g, data, idx))


def _gains(model, data: np.ndarray, width: float, idx: np.ndarray) -> np.ndarray:
    """Unconstrained best-fit gain at the centres of the cells ``idx`` (m, K) of ``width`` rad."""
    used, idx = np.unique(idx, return_inverse=True)  # (m, K) indices into used
    g = unit_responses(model, -math.pi + width * (used + 0.5))
    return _pair_gains(g, data, idx)


def _grid(k: int, n: int) -> np.ndarray:
    """All cells (n^K, K) of an n-point grid per direction."""
    return np.stack(np.meshgrid(*[np.arange(n)] * k, indexing="ij"), -1).reshape(-1, k)


def _refine(kept: np.ndarray, r: int) -> np.ndarray:
    """The r^K fine cells (m r^K, K) inside each coarse cell of ``kept`` (m, K)."""
    sub = _grid(kept.shape[1], r)
    return (kept[:, None, :] * r + sub[None, :, :]).reshape(-1, kept.shape[1])


def _slack(k: int, width, sd):
    """Curvature slack (nats): the largest drop of log L from a cell's best point to its centre.

    ``_SAFETY`` times the quadratic estimate ``0.5 sum_j (width_j / 2)^2 / sd_j^2``
    (``0.5 K (width / 2)^2 / sd^2`` for square cells) at the curvature ``1 / sd^2``.
    """
    if np.ndim(width) == 0 and np.ndim(sd) == 0:
        return _SAFETY * 0.5 * k * (0.5 * width / sd) ** 2
    return _SAFETY * 0.5 * np.sum((0.5 * width / sd) ** 2, axis=-1)


def _coarse(model, data: np.ndarray, k: int, sd: float, margin: float, budget: float
            ) -> tuple[np.ndarray, int]:
    """The coarse cells (m, K) within ``margin`` plus the slack of the best, and n0."""
    n0 = min(max(64, math.ceil(2 * math.pi / (_COARSE * sd))), int(budget ** (1 / k)))
    w0 = 2 * math.pi / n0
    cells = _grid(k, n0)
    ll = _gains(model, data, w0, cells) / (2 * model.sigma**2)
    return cells[ll >= np.max(ll) - margin - _slack(k, w0, sd)], n0


def cell_budget() -> float:
    """Cells per level the memory budget and :data:`_MAX_CELLS` allow."""
    return min(memory_limit() / _BYTES_PER_CELL, _MAX_CELLS)


def screen(model, data: np.ndarray, k: int, sd: float, margin: float, lo: float
           ) -> Cells | str:
    """Fine cells worth integrating, or why none.

    Coarse cells of ~``_COARSE`` sd (fewer when the grid would exceed the cell
    budget) are kept when their centre's bound is within ``margin`` plus the
    curvature slack of the best; each is split into r^K square fine cells of
    ~``_FINE`` sd, kept on the same rule.  Where the fine cells would exceed the
    budget, or more than ``_MAX_DRAWN`` are kept, r is halved, down to cells of
    ``_WIDEST`` sd (a larger stated error, which the caller checks); beyond
    that, two directions get cells aligned with the likelihood
    (:func:`aligned_cells`).
    """
    cap = cell_budget()
    kept, n0 = _coarse(model, data, k, sd, margin, cap)
    s2, w0 = 2 * model.sigma**2, 2 * math.pi / n0
    r, r_min = (max(1, math.ceil(w0 / (f * sd))) for f in (_FINE[k - 1], _WIDEST))
    while True:
        if float(len(kept)) * r**k <= cap:
            fine, n1 = _refine(kept, r), n0 * r
            ll = _gains(model, data, 2 * math.pi / n1, fine) / s2
            fine = fine[ll >= np.max(ll) - margin - _slack(k, 2 * math.pi / n1, sd)]
            if len(fine) <= _MAX_DRAWN:
                return Cells(fine, np.full(fine.shape, 2 * math.pi / n1), n1)
        if r <= r_min:
            break
        r = max(r_min, r // 2)
    why = (f"{len(kept)} coarse cells of {n0}^{k} kept, beyond the budget of "
           f"{min(cap, _MAX_DRAWN):.3g} fine cells of {_WIDEST:g} sd")
    found = aligned_cells(model, data, kept, n0, sd, margin, cap, lo) if k == 2 else None
    return why + " (square or aligned)" if found is None else found


def _bound_log_likelihood(g: np.ndarray, data: np.ndarray, idx: np.ndarray, lo: float,
                          s2: float) -> np.ndarray:
    """Upper bound of log L (to a constant) over intensities >= ``lo``, pairs ``idx`` (m, 2).

    ``-min |y - G I|^2 / s2`` over ``I >= lo``: with ``y' = y - lo (g_i + g_j)`` the
    best non-negative ``I - lo`` is the unconstrained one when both are
    non-negative, else the better of the two one-direction fits with a
    non-negative intensity.  Tighter than :func:`projection_gain` where two
    nearly coincident directions would need intensities of opposite sign.
    """
    gi, gj, ai, aj, b = _pair_terms(g, data, idx)
    ui, uj = gi - lo * (ai + b), gj - lo * (b + aj)  # g . y'
    yy = data @ data - 2 * lo * (gi + gj) + lo * lo * (ai + 2 * b + aj)
    xi, xj, ok = _pair_solve(ui, uj, ai, aj, b)
    inside = ok & (xi >= 0) & (xj >= 0)
    face = np.maximum(np.maximum(ui, 0) ** 2 / ai, np.maximum(uj, 0) ** 2 / aj)
    return (np.where(inside, xi * ui + xj * uj, face) - yy) / s2


def _local_widths(model, data: np.ndarray, centres: np.ndarray, sd: float) -> np.ndarray:
    """Posterior width (rad, >= ``sd``) along each of two directions at ``centres`` (m, 2).

    ``sigma / (|I_j| |dg/dtheta_j|)``: the Gauss-Newton curvature of log L along
    ``theta_j`` with the intensities at their unconstrained best; ``sd`` where the
    two directions coincide to rounding.
    """
    used, inv = np.unique(centres, return_inverse=True)
    inv = inv.reshape(centres.shape)
    slope = (unit_responses(model, used + _STEP) - unit_responses(model, used - _STEP)) / (
        2 * _STEP)
    xi, xj, ok = _pair_solve(*_pair_terms(unit_responses(model, used), data, inv))
    best = np.stack([xi, xj], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        width = model.sigma / (np.abs(best) * np.sqrt(np.einsum("ij,ij->i", slope, slope))[inv])
    return np.where(ok[:, None] & (width > sd), width, sd)


def _split(kept: np.ndarray, r: np.ndarray, w0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The r[c, 0] x r[c, 1] fine cells of each coarse cell ``kept[c]`` (m, 2) of width w0.

    Returns the fine cells' indices (M, 2), widths (M, 2) and coarse cell (M,).
    """
    counts = r[:, 0] * r[:, 1]
    owner = np.repeat(np.arange(len(kept)), counts)
    within = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    ro = r[owner]
    sub = np.stack([within // ro[:, 1], within % ro[:, 1]], -1)
    return kept[owner] * ro + sub, w0 / ro, owner


def aligned_cells(model, data: np.ndarray, kept: np.ndarray, n0: int, sd: float,
                  margin: float, budget: float, lo: float) -> Cells | None:
    """Fine cells of two directions sized per coarse cell and direction, or None.

    Each coarse cell of ``kept`` (m, 2), width ``2 pi / n0``, is split into cells
    of ~``_FINE`` local posterior widths per direction (:func:`_local_widths`),
    kept when their centre's bound lies within ``margin`` plus their own
    curvature slack of the best; the coarse cells themselves are first screened
    again on that bound.  Over the budget the splits are capped, halving the cap
    down to cells of ``_WIDEST_ALIGNED`` sd (the stated error then grows, and
    the caller checks it); None when even that exceeds the budget.
    """
    w0, s2 = 2 * math.pi / n0, 2 * model.sigma**2
    used, inv = np.unique(kept, return_inverse=True)
    ll = _bound_log_likelihood(unit_responses(model, -math.pi + w0 * (used + 0.5)), data,
                               inv.reshape(kept.shape), lo, s2)
    kept = kept[ll >= np.max(ll) - margin - _slack(2, w0, sd)]
    local = _local_widths(model, data, -math.pi + w0 * (kept + 0.5), sd)
    full = np.maximum(1, np.ceil(w0 / (_FINE[1] * local))).astype(np.int64)
    cap, r_min = int(full.max()), max(1, math.ceil(w0 / (_WIDEST_ALIGNED * sd)))
    while True:
        r = np.minimum(full, cap)
        if float(np.sum(r[:, 0] * r[:, 1])) <= budget:
            idx, width, owner = _split(kept, r, w0)
            used, inv = np.unique(-math.pi + width * (idx + 0.5), return_inverse=True)
            if used.size * model.n_sensors * 8.0 > memory_limit() / 4:
                return None
            ll = _bound_log_likelihood(unit_responses(model, used), data,
                                       inv.reshape(idx.shape), lo, s2)
            keep = ll >= np.max(ll) - margin - _slack(2, width, local[owner])
            if np.count_nonzero(keep) <= _MAX_DRAWN:
                return Cells(idx[keep], width[keep], n0 * int(r.max()))
        if cap <= r_min:
            return None
        cap = max(r_min, cap // 2)
