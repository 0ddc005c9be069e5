"""Laplace evidence and the closed forms it is checked against.

For K exchangeable sources the prior pi(x) is a product over sources on the full
(labelled) parameter space, so the posterior has K! symmetric modes, one per
labelling.  An ML fit returns one of them (the canonical, ordered one); when the
modes are well apart each holds the same mass, and

    log Z_K = log L(x^) + log pi(x^) + (P/2) log 2 pi - 1/2 log det H + log K!

with H the Hessian of -log L (for Gaussian noise at the ML point, the Fisher
matrix J^T J / sigma^2).  The same number is obtained from the ordered prior
K! pi(x) on the ordered region (one mode): either way nested sampling over the
full space with the unordered prior, and this formula, estimate the same Z_K.
Sources whose intensity Gaussian reaches below 0 (the prior's edge) get the
factor Phi(I^/sd_I) of the mass left inside the support.
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import finite_array, positive_float
from ..bounds import SINGULAR_RTOL, equilibrate
from ..errors import InputError

__all__ = [
    "laplace_log_evidence",
    "noise_log_evidence",
    "linear_gaussian_log_evidence",
]

LOG_2PI = math.log(2.0 * math.pi)


def noise_log_evidence(data: np.ndarray, sigma: float) -> np.ndarray:
    """Closed-form evidence of K = 0 (noise only): log N(data; 0, sigma^2 I).

    Parameters
    ----------
    data : ndarray, shape (..., N)
        Readings.
    sigma : float
        Noise std (reading units).

    Returns
    -------
    ndarray, shape (...,)
        log Z_0 in nats (no free parameters, so Z_0 is the likelihood itself).
    """
    s = finite_array("data", data)
    sigma = positive_float("sigma", sigma)
    n = s.shape[-1]
    return -0.5 * np.einsum("...n,...n->...", s, s) / sigma**2 - n * (
        math.log(sigma) + 0.5 * LOG_2PI
    )


def laplace_log_evidence(
    log_likelihood: float,
    log_prior: float,
    hessian: np.ndarray,
    *,
    n_exchangeable: int = 0,
    log_support_mass: float = 0.0,
) -> float:
    """Laplace approximation of log Z around a mode.

    Parameters
    ----------
    log_likelihood, log_prior : float
        log L and log pi at the mode (nats).
    hessian : ndarray, shape (P, P)
        Hessian of -log(L pi) at the mode (or the Fisher matrix when the prior is
        flat there); must be positive definite.
    n_exchangeable : int
        Number K of exchangeable sources: adds log K! for the K! symmetric modes
        of the unordered prior (0 or 1: no factor).
    log_support_mass : float
        log of the Gaussian mass inside the prior's support (<= 0), e.g. the sum
        of log Phi(I^/sd_I) over intensities bounded below by 0.

    Returns
    -------
    float
        log Z (nats); -inf if the prior density is 0 at the mode, NaN if the
        Hessian is not positive definite.
    """
    from scipy.special import gammaln  # on use: scipy is slow to import
    h = finite_array("hessian", hessian, ndim=2, allow_empty=True)
    if h.shape[0] != h.shape[1]:
        raise InputError(f"hessian must be square; got shape {h.shape}")
    if n_exchangeable < 0:
        raise InputError(f"n_exchangeable must be >= 0; got {n_exchangeable}")
    if not np.isfinite(log_likelihood) or np.isnan(log_prior):
        return math.nan
    if log_prior == -np.inf:
        return -math.inf
    p = h.shape[0]
    if p == 0:
        return float(log_likelihood + log_prior)
    sign, logdet = np.linalg.slogdet(h)
    if sign <= 0 or not np.isfinite(logdet):
        return math.nan
    return float(
        log_likelihood
        + log_prior
        + 0.5 * p * LOG_2PI
        - 0.5 * logdet
        + gammaln(n_exchangeable + 1)
        + log_support_mass
    )


def intensity_support_mass(intensity: np.ndarray, intensity_sd: np.ndarray) -> float:
    """sum_k log Phi(I_k / sd_k): Gaussian mass of each intensity left above 0."""
    from scipy.special import log_ndtr  # on use: scipy is slow to import
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(intensity_sd > 0, intensity / intensity_sd, np.inf)
    return float(np.sum(log_ndtr(z)))


def linear_gaussian_log_evidence(
    design: np.ndarray,
    data: np.ndarray,
    sigma: float,
    prior_mean: np.ndarray,
    prior_cov: np.ndarray,
) -> float:
    """Exact evidence of ``data = design @ a + noise`` with a ~ N(m, S).

    The marginal of the data is N(design m, sigma^2 I + design S design^T); this is
    the imaging model of Eq. 1 with known directions and a Gaussian intensity
    prior, where the Laplace approximation is exact.

    Parameters
    ----------
    design : ndarray, shape (N, P)
    data : ndarray, shape (N,)
    sigma : float
    prior_mean : ndarray, shape (P,)
    prior_cov : ndarray, shape (P, P), positive definite

    Returns
    -------
    float
        log Z (nats).
    """
    a = finite_array("design", design, ndim=2)
    s = finite_array("data", data, ndim=1, last=a.shape[0])
    m = finite_array("prior_mean", prior_mean, ndim=1, last=a.shape[1])
    cov_p = finite_array("prior_cov", prior_cov, ndim=2)
    sigma = positive_float("sigma", sigma)
    c = sigma**2 * np.eye(a.shape[0]) + a @ cov_p @ a.T
    chol = np.linalg.cholesky(c)
    r = np.linalg.solve(chol, s - a @ m)
    return float(-0.5 * r @ r - np.sum(np.log(np.diag(chol))) - 0.5 * a.shape[0] * LOG_2PI)


def support_log_mass(params: np.ndarray, sd: np.ndarray, prior) -> np.ndarray:
    """log of the Gaussian mass inside the prior's box, summed over parameters.

    For every non-periodic parameter with mean ``params`` and sd ``sd`` the mass
    Phi((upper - x)/sd) - Phi((lower - x)/sd) of its Gaussian inside the prior's
    support (an intensity at its lower edge 0 keeps half).  A periodic parameter
    (ring angle, longitude) whose Gaussian is wider than its period L contributes
    log(L / (sqrt(2 pi) sd)) < 0, capping its Laplace volume at the whole prior
    (the direction of a weak source is not localised).  Shapes: params, sd
    (..., P) -> (...,).
    """
    from scipy.special import log_ndtr  # on use: scipy is slow to import
    lo, hi = prior.lower, prior.upper
    per = prior.periodic
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(per, -np.inf, (lo - params) / sd)
        b = np.where(per, np.inf, (hi - params) / sd)
        # log(Phi(b) - Phi(a)) computed on the side that keeps precision
        box = log_ndtr(b) + np.log1p(-np.exp(np.minimum(log_ndtr(a) - log_ndtr(b), 0.0)))
        wide = np.minimum(0.0, np.log(hi - lo) - np.log(math.sqrt(2 * math.pi) * sd))
        term = np.where(per, wide, box)
    return np.sum(np.where(np.isfinite(sd), term, np.nan), axis=-1)


def prior_precision(prior, n_grid: int = 2048) -> np.ndarray:
    """1 / variance of every flat parameter's 1-D prior, shape (P,).

    Variances by quantile integration of ``ppf`` (a circular uniform angle gets
    (2 pi)^2 / 12, its variance on the unwrapped interval).
    """
    u = (np.arange(n_grid) + 0.5) / n_grid
    out = []
    for m in prior.marginals:
        x = np.asarray(m.ppf(u), float)
        out.append(1.0 / max(float(np.var(x)), 1e-300))
    return np.array(out)


def model_laplace(
    model,
    params: np.ndarray,
    log_likelihood: np.ndarray,
    prior,
    *,
    ridge: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched Laplace evidence of K exchangeable sources at ML points.

    Parameters
    ----------
    model : Model
    params : ndarray, shape (..., P)
        ML points (any labelling; the K! term counts the other labellings).
    log_likelihood : ndarray, shape (...,)
        Maximum log-likelihood at ``params``.
    prior : ScenePrior
        Prior of K sources (sigma known).
    ridge : bool
        Add the prior's precision (1 / prior variance) to the Fisher matrix, as
        if the prior were Gaussian with its variance.  Makes a singular Fisher
        matrix usable: each unidentifiable direction then spans about the whole
        prior, which over-estimates Z when the degenerate set is short (a rough
        fallback, never trusted).

    Returns
    -------
    log_z : ndarray, shape (...,)
        Laplace log Z_K (nats); NaN where the Fisher matrix is singular.
    fisher : ndarray, shape (..., P, P)
    sd : ndarray, shape (..., P)
        sqrt(diag(F^-1)) (NaN where singular).
    """
    x = np.asarray(params, float)
    ll = np.asarray(log_likelihood, float)
    fisher = model.fisher(x)
    if ridge:
        fisher = fisher + np.diag(prior_precision(prior))
    sign, logdet = np.linalg.slogdet(fisher)
    f, d = equilibrate(fisher)
    w = np.linalg.eigvalsh(f)
    # singular by the same rule as olsbayes.bounds.bound_covariance
    ok = (sign > 0) & np.isfinite(logdet) & (w[..., 0] > SINGULAR_RTOL * w[..., -1])
    safe = np.where(ok[..., None, None], f, np.eye(x.shape[-1]))
    cov = np.linalg.inv(safe) * d[..., :, None] * d[..., None, :]
    var = np.diagonal(cov, axis1=-2, axis2=-1)
    ok = ok & np.all(var > 0, axis=-1)  # numerically indefinite inverse: treat as singular
    sd = np.sqrt(np.where(ok[..., None] & (var > 0), var, np.nan))
    p = x.shape[-1]
    log_z = (
        ll
        + prior.log_prob(x)
        + 0.5 * p * LOG_2PI
        - 0.5 * np.where(ok, logdet, np.nan)
        + prior.log_label_factor
        + support_log_mass(x, sd, prior)
    )
    return log_z, fisher, sd
