"""Gibbs along the eigenvectors of the precision, for box-truncated Gaussians.

Target on the box ``lower <= x <= upper`` (bounds may be infinite)::

    p(x) ∝ exp(-x^T Q x / 2 + b^T x),   Q symmetric positive semi-definite.

Single-site Gibbs moves along the coordinate axes; when ``Q`` has a null space
(an imaging design with more sources than independent readings) or is badly
conditioned, the slow directions of the posterior are combinations of many
intensities and coordinate moves crawl along them.  This sampler also moves
along every eigenvector ``u_j`` of ``Q = V diag(lambda) V^T`` (a hit-and-run
whose direction set is the eigenbasis, visited in random order each sweep).
Along ``x + t u`` the conditional of ``t`` is exactly a 1-D normal with
precision ``lambda_j`` and mean ``u^T (b - Q x) / lambda_j``, truncated to the
segment between the box walls -- drawn exactly with :func:`truncnorm_1d`.
For null directions (``lambda_j * width^2 < 1e-8``) the quadratic term is
dropped (relative density error below 1e-8) and ``t`` is drawn exactly from the
exponentially tilted uniform ``exp(h t)`` on the segment.  Each sweep is a
coordinate sweep followed by an eigen sweep; ``Q x`` is kept up to date in
O(K) per move (``Q u_j = lambda_j u_j``) and recomputed every sweep.
"""

from __future__ import annotations

import numpy as np

from .truncated import TruncatedSamples, truncnorm_1d

__all__ = ["eigen_gibbs"]

_FLAT = 1e-8  # lambda * width^2 below this: the quadratic term is dropped


def _segment(x, u, lower, upper):
    """Range (t_lo, t_hi), shapes (C,), of t with lower <= x + t u <= upper."""
    nz = np.abs(u) > 1e-12 * np.abs(u).max()
    un, xn = u[nz], x[:, nz]
    with np.errstate(invalid="ignore"):
        a = (lower[nz] - xn) / un
        b = (upper[nz] - xn) / un
    lo = np.where(un > 0, a, b)
    hi = np.where(un > 0, b, a)
    t_lo = np.minimum(np.nanmax(lo, axis=1), 0.0)  # x is inside: t = 0 is feasible
    t_hi = np.maximum(np.nanmin(hi, axis=1), 0.0)
    return t_lo, t_hi


def _tilted_uniform(h, lo, hi, rng):
    """Exact draws of t on [lo, hi] with density ∝ exp(h t) (finite lo, hi)."""
    w = hi - lo
    a = np.abs(h)
    u = rng.random(h.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -np.log1p(-u * -np.expm1(-a * w)) / a  # density ∝ exp(-a s) on [0, w]
    s = np.where(a * w < 1e-12, u * w, np.clip(s, 0.0, w))
    return np.where(h > 0, hi - s, lo + s)


def _line_draw(h, lam, lo, hi, rng):
    """t ~ exp(h t - lam t^2 / 2) on [lo, hi], per chain."""
    w = hi - lo
    flat = np.isfinite(w) & (lam * w**2 < _FLAT)
    out = np.empty_like(h)
    if np.any(flat):
        out[flat] = _tilted_uniform(h[flat], lo[flat], hi[flat], rng)
    if np.any(~flat):
        lam_s = max(lam, 1e-300)
        g = ~flat
        out[g] = truncnorm_1d(h[g] / lam_s, 1.0 / np.sqrt(lam_s), lo[g], hi[g], rng=rng)
    return np.clip(out, lo, hi)


def eigen_gibbs(
    precision: np.ndarray,
    linear: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    x0: np.ndarray,
    n_samples: int,
    *,
    rng: np.random.Generator,
    n_burn: int = 100,
    coordinate: bool = True,
) -> TruncatedSamples:
    """Draws of ``exp(-x^T Q x / 2 + b^T x)`` on a box by coordinate + eigen Gibbs.

    Parameters
    ----------
    precision : ndarray, shape (K, K)
        Q, symmetric positive semi-definite.
    linear : ndarray, shape (K,)
        b (must be orthogonal to Q's null space when a bound is infinite along it).
    lower, upper : ndarray, shape (K,)
        Box bounds (may be -inf / inf; lower < upper).
    x0 : ndarray, shape (C, K)
        Starting points of C chains inside the box.
    n_samples, n_burn : int
        Kept and discarded sweeps per chain.
    coordinate : bool
        Also run a single-site sweep before each eigen sweep.

    Returns
    -------
    TruncatedSamples
        ``samples`` (C, n_samples, K); acceptance 1 (every move is an exact
        Gibbs draw) and ``mean_bounces`` 0.
    """
    q = 0.5 * (precision + precision.T)
    lam, vec = np.linalg.eigh(q)
    lam = np.maximum(lam, 0.0)
    vt = np.ascontiguousarray(vec.T)
    ub = vt @ linear
    qd = np.diag(q)
    x = np.clip(np.array(x0, dtype=float), lower, upper)
    c, k = x.shape
    out = np.empty((c, n_samples, k))
    for sweep in range(n_burn + n_samples):
        qx = x @ q
        if coordinate:
            for j in rng.permutation(k):
                if qd[j] <= 0:
                    continue
                m = x[:, j] + (linear[j] - qx[:, j]) / qd[j]
                new = truncnorm_1d(m, 1.0 / np.sqrt(qd[j]), lower[j], upper[j], rng=rng)
                qx += np.outer(new - x[:, j], q[j])
                x[:, j] = new
        for j in rng.permutation(k):
            u = vt[j]
            h = ub[j] - lam[j] * (x @ u)
            lo, hi = _segment(x, u, lower, upper)
            t = _line_draw(h, lam[j], lo, hi, rng)
            x += np.outer(t, u)
        x = np.clip(x, lower, upper)  # round-off at the walls
        if sweep >= n_burn:
            out[:, sweep - n_burn] = x
    return TruncatedSamples(out, 1.0, 0.0)
