"""Exact reference posterior of one or two ring sources, for calibration checks.

On a ring the readings are linear in the intensities, ``y = G(theta) I + noise``, so
for fixed directions the intensities have a Gaussian likelihood that can be
integrated exactly.  The posterior of the directions is then a function on the
circle (K = 1) or the torus (K = 2): it is evaluated on a grid, the cells within
``margin`` log-units of the best are kept, and each kept cell gets ``per_cell``
importance draws -- directions uniform in the cell, intensities from the
unconstrained Gaussian ``N(I_hat, sigma^2 (G^T G)^-1)`` -- with weight

    exp(-chi2_min / 2 sigma^2) sqrt(det(sigma^2 (G^T G)^-1)) 1[I in (0, i_max)^K],

the posterior over the proposal (flat priors: uniform directions, intensities
Uniform(0, i_max)).  No Markov chain, so no mode can be missed: it is an
independent check of :func:`olsbayes.posterior.sample`.  :func:`sbc_exact` is
the SBC replicate of this posterior; with the same study seed as
:func:`~olsbayes.studies.sbc.sbc_posterior` it sees exactly the same scenes, so
the two coverages can be compared pairwise (the scenes' own fluctuation cancels).
"""

from __future__ import annotations

import numpy as np

from .._validation import as_rng
from ..errors import InputError
from ..select.quadrature import projection_gain, unit_responses
from ._work import trial_outputs, trial_settings
from .sbc import _prior
from .trials import ring_model

__all__ = ["exact_ring_posterior", "weighted_cdf", "sbc_exact"]


def _screen(model, data: np.ndarray, k: int, n_grid: int, margin: float) -> np.ndarray:
    """Grid cells (m, k) of angle indices near the grid's best log-likelihood.

    Kept: cells whose best unconstrained log-likelihood is within ``margin`` of the
    grid's best (an upper bound: the box is ignored).
    """
    th = -np.pi + 2 * np.pi * np.arange(n_grid) / n_grid
    g = unit_responses(model, th)
    gd = g @ data
    if k == 1:
        q = projection_gain(gd, None, np.einsum("ij,ij->i", g, g))
    else:
        gram = g @ g.T
        a = np.diag(gram)
        q = projection_gain(gd[:, None], gd[None, :], a[:, None], a[None, :], gram)
    ll = 0.5 * q / model.sigma**2
    return np.argwhere(ll > np.max(ll) - margin).reshape(-1, k)


def exact_ring_posterior(model, data: np.ndarray, n_sources: int, i_max: float, *,
                         rng: np.random.Generator | int | None = None, n_grid: int = 512,
                         per_cell: int = 4, margin: float = 40.0
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted draws of the posterior of 1 or 2 ring sources.

    Uniform directions, intensities Uniform(0, i_max), known sigma.

    Parameters
    ----------
    model : Model
        A ring model (``kind == "angle"``).
    data : ndarray (N,)
    n_sources : {1, 2}
    i_max : float
    rng : Generator or int, optional
    n_grid : int
        Grid points per direction (cell width 2 pi / n_grid rad).
    per_cell : int
        Importance draws per kept cell.
    margin : float
        Cells whose unconstrained best log-likelihood is more than ``margin`` below
        the grid's best are dropped.

    Returns
    -------
    draws : ndarray (S, 2K)
        In canonical order (:meth:`Model.canonical`).
    weights : ndarray (S,)
        Normalised importance weights.
    """
    if model.kind != "angle":
        raise InputError(
            f"exact_ring_posterior needs a ring model (kind 'angle'); got {model.kind!r}")
    k = int(n_sources)
    if k not in (1, 2):
        raise InputError(f"n_sources must be 1 or 2; got {n_sources!r}")
    gen = as_rng(rng)
    data = np.asarray(data, dtype=float)
    cells = np.repeat(_screen(model, data, k, int(n_grid), float(margin)), per_cell, axis=0)
    n, h = len(cells), 2 * np.pi / n_grid
    theta = -np.pi + h * (cells + gen.uniform(-0.5, 0.5, cells.shape))  # (n, k)
    g = unit_responses(model, theta.ravel()).reshape(n, k, -1).swapaxes(1, 2)  # (n, N, k)
    gram = np.einsum("nsi,nsj->nij", g, g)
    sign, logdet = np.linalg.slogdet(gram)
    # two directions equal to rounding (a null set): G^T G is singular, the draw is dropped
    ok = (sign > 0) & (logdet > np.sum(np.log(np.diagonal(gram, axis1=1, axis2=2)), -1) - 25)
    theta, g, gram, logdet = theta[ok], g[ok], gram[ok], logdet[ok]
    cov = np.linalg.inv(gram) * model.sigma**2
    rhs = np.einsum("nsi,s->ni", g, data) / model.sigma**2
    i_hat = np.einsum("nij,nj->ni", cov, rhs)
    chi2_min = (data @ data / model.sigma**2 - np.einsum("ni,ni->n", i_hat, rhs))
    root = np.linalg.cholesky(0.5 * (cov + cov.swapaxes(1, 2)))
    inten = i_hat + np.einsum("nij,nj->ni", root, gen.standard_normal(i_hat.shape))
    inside = np.all((inten >= 0) & (inten <= i_max), axis=-1)
    log_det_cov = k * np.log(model.sigma**2) - logdet
    logw = np.where(inside, -0.5 * chi2_min + 0.5 * log_det_cov, -np.inf)
    if not np.any(np.isfinite(logw)):
        raise InputError("exact_ring_posterior: no draw inside the intensity prior; "
                         "increase per_cell or n_grid")
    w = np.exp(logw - np.max(logw))
    x = np.stack([theta, inten], axis=-1).reshape(len(theta), 2 * k)
    return model.canonical(x), w / w.sum()


def weighted_cdf(draws: np.ndarray, weights: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Posterior probability (P,) that each coordinate of ``draws`` (S, P) is below ``value``."""
    return np.asarray(weights) @ (np.asarray(draws) < np.asarray(value))


@trial_outputs(cdf=("posterior CDF at the true value, per parameter", "1"),
               ess=("effective number of importance draws", ""))
@trial_settings("n_sensors", "sigma", "n_sources", "i_max", "n_grid")
def sbc_exact(settings: dict, *, rng: np.random.Generator) -> dict:
    """One SBC replicate of :func:`exact_ring_posterior`.

    Same settings and random stream as :func:`~olsbayes.studies.sbc.sbc_posterior` (so
    the same scene for the same seed).

    Returns ``cdf`` (P,): posterior probability below the canonical truth, uniform on
    (0, 1) for an exact posterior; ``ess``: effective number of importance draws.
    """
    model = ring_model(settings)
    k = int(settings.get("n_sources", 1))
    prior = _prior(model, settings, k)
    truth = prior.sample(rng=rng)
    data = model.simulate(truth, rng=rng)
    draws, w = exact_ring_posterior(model, data, k, float(settings.get("i_max", 2.0)), rng=rng,
                                    n_grid=int(settings.get("n_grid", 512)))
    return {"cdf": weighted_cdf(draws, w, model.canonical(truth)), "ess": 1.0 / np.sum(w * w)}
