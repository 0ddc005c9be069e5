"""Exact evidence of 1-2 ring sources by quadrature (uniform directions, flat box intensities).

The intensities are integrated analytically for fixed directions (Gaussian
likelihood, box prior) and the directions on a fine grid with stratified draws
-- the construction of :mod:`olsbayes.studies.sbc_exact`, summed into log Z with
its own Monte Carlo standard error.  Written apart from the package's grid code
(its screen solves the least-squares problem of every grid cell with numpy), so
that :mod:`olsbayes.select.quadrature` is checked against code it does not share.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

__all__ = ["exact_log_evidence"]


def _unit_responses(model, theta: np.ndarray) -> np.ndarray:
    """Readings (n, N) of unit-intensity sources at angles ``theta`` (n,)."""
    return model.response(np.column_stack([theta, np.ones_like(theta)]))


def _screen(model, data: np.ndarray, k: int, ngrid: int, margin: float) -> np.ndarray:
    """Grid cells (m, k) whose unconstrained least-squares fit at the grid point is within
    ``margin`` nats of the best (coincident directions: the one-source fit)."""
    g = _unit_responses(model, -np.pi + 2 * np.pi * np.arange(ngrid) / ngrid)  # (n, N)
    single = (g @ data) ** 2 / np.sum(g * g, axis=1)  # |projection|^2 on one direction
    if k == 1:
        gain = single
    else:
        i, j = np.triu_indices(ngrid, 1)
        a = np.stack([g[i], g[j]], axis=-1)  # (pairs, N, 2)
        gram = np.einsum("psi,psj->pij", a, a)
        rhs = np.einsum("psi,s->pi", a, data)
        pair = np.einsum("pi,pi->p", np.linalg.solve(gram, rhs[..., None])[..., 0], rhs)
        gain = np.maximum.outer(single, single)
        gain[i, j] = gain[j, i] = np.maximum(pair, gain[i, j])
    ll = 0.5 * gain / model.sigma**2
    return np.argwhere(ll > np.max(ll) - margin).reshape(-1, k)


def exact_log_evidence(model, data: np.ndarray, k: int, i_max: float, seed: int,
                       ngrid: int = 256, per_cell: int = 4) -> tuple[float, float]:
    """log Z_K (uniform directions, intensities Uniform(0, i_max)) and its standard error:
    grid cells within 40 nats of the best, ``per_cell`` uniform draws in each, the
    intensities drawn from their conditional Gaussian and kept inside the box."""
    rng = np.random.default_rng(seed)
    s2, n_s = model.sigma**2, model.n_sensors
    cells = np.repeat(_screen(model, data, k, ngrid, 40.0), per_cell, axis=0)
    n, h = len(cells), 2 * np.pi / ngrid
    theta = -np.pi + h * (cells + rng.uniform(-0.5, 0.5, cells.shape))
    g = _unit_responses(model, theta.ravel()).reshape(n, k, -1).swapaxes(1, 2)
    gram = np.einsum("nsi,nsj->nij", g, g)
    sign, logdet = np.linalg.slogdet(gram)
    ok = (sign > 0) & (logdet > np.sum(np.log(np.diagonal(gram, axis1=1, axis2=2)), -1) - 25)
    gram = np.where(ok[:, None, None], gram, np.eye(k))
    cov = np.linalg.inv(gram) * s2
    rhs = np.einsum("nsi,s->ni", g, data) / s2
    i_hat = np.einsum("nij,nj->ni", cov, rhs)
    chi2 = data @ data / s2 - np.einsum("ni,ni->n", i_hat, rhs)
    root = np.linalg.cholesky(0.5 * (cov + cov.swapaxes(1, 2)))
    inten = i_hat + np.einsum("nij,nj->ni", root, rng.standard_normal((n, k)))
    inside = ok & np.all((inten >= 0) & (inten <= i_max), axis=-1)
    log_w = np.where(inside, -0.5 * chi2 + 0.5 * np.log(np.linalg.det(cov))
                     + 0.5 * k * math.log(2 * math.pi), -np.inf)
    log_mean = logsumexp(log_w) - math.log(n)
    w = np.exp(log_w - log_mean)
    # sum over kept cells of the in-cell mean, times the cell area h^k and the prior density
    log_z = (-0.5 * n_s * math.log(2 * math.pi * s2) - k * math.log(2 * np.pi * i_max)
             + k * math.log(h) + log_mean + math.log(n / per_cell))
    return float(log_z), float(np.std(w) / math.sqrt(n))
