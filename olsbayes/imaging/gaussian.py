"""Closed-form linear-Gaussian posterior and evidence.

Model ``y = A I + e`` with ``e ~ N(0, sigma^2 1_N)`` and prior
``I ~ N(m0, diag(tau^2))``.  The posterior is Gaussian with precision
``P = A^T A / sigma^2 + diag(1 / tau^2)`` and mean
``P^{-1} (A^T y / sigma^2 + m0 / tau^2)``; the evidence is
``y ~ N(A m0, sigma^2 1_N + A diag(tau^2) A^T)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GaussianPosterior", "gaussian_posterior", "log_evidence"]


@dataclass(frozen=True)
class GaussianPosterior:
    """Posterior of the intensities under a Gaussian prior.

    Attributes
    ----------
    mean : ndarray, shape (K,)
        Posterior mean (= mode).
    cov : ndarray, shape (K, K)
        Posterior covariance.
    log_evidence : float
        log p(y) under the prior, natural log, y in reading units.
    """

    mean: np.ndarray
    cov: np.ndarray
    log_evidence: float

    @property
    def sd(self) -> np.ndarray:
        """Posterior standard deviations, shape (K,)."""
        return np.sqrt(np.diag(self.cov))


def gaussian_posterior(
    a: np.ndarray, y: np.ndarray, sigma: float, prior_mean: np.ndarray, prior_sd: np.ndarray
) -> GaussianPosterior:
    """Posterior mean, covariance and evidence of the linear-Gaussian model.

    Parameters
    ----------
    a : ndarray, shape (N, K)
        Design matrix.
    y : ndarray, shape (N,)
        Readings.
    sigma : float
        Noise sd of one reading.
    prior_mean, prior_sd : ndarray, shape (K,)
        Independent Gaussian prior of each intensity (prior_sd > 0).
    """
    from scipy.linalg import cho_factor, cho_solve  # on use: scipy is slow to import
    w = 1.0 / prior_sd**2
    prec = a.T @ a / sigma**2 + np.diag(w)
    cf = cho_factor(prec, lower=True)
    mean = cho_solve(cf, a.T @ y / sigma**2 + w * prior_mean)
    cov = cho_solve(cf, np.eye(a.shape[1]))
    cov = 0.5 * (cov + cov.T)
    return GaussianPosterior(mean, cov, log_evidence(a, y, sigma, prior_mean, prior_sd))


def log_evidence(
    a: np.ndarray, y: np.ndarray, sigma: float, prior_mean: np.ndarray, prior_sd: np.ndarray
) -> float:
    """log N(y; A m0, sigma^2 1 + A diag(tau^2) A^T), by a Cholesky factor of size N."""
    from scipy.linalg import solve_triangular  # on use: scipy is slow to import
    n = a.shape[0]
    cov = sigma**2 * np.eye(n) + (a * prior_sd**2) @ a.T
    chol = np.linalg.cholesky(cov)
    z = solve_triangular(chol, y - a @ prior_mean, lower=True)
    logdet = 2.0 * np.sum(np.log(np.diag(chol)))
    return float(-0.5 * (z @ z) - 0.5 * logdet - 0.5 * n * np.log(2.0 * np.pi))
