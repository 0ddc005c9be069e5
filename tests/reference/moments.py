"""Reference moments for the sampler tests: batch-means standard errors and the exact
moments of a Gaussian truncated to a 2-D box (by quadrature)."""

from __future__ import annotations

import numpy as np
from scipy import integrate

__all__ = ["batch_se", "box_moments_2d"]


def batch_se(draws: np.ndarray, n_batches: int = 20) -> np.ndarray:
    """Monte Carlo standard error of the mean by batch means; draws (S, ...)."""
    s = draws.shape[0] - draws.shape[0] % n_batches
    means = draws[:s].reshape((n_batches, -1) + draws.shape[1:]).mean(axis=1)
    return means.std(axis=0, ddof=1) / np.sqrt(n_batches)


def box_moments_2d(q: np.ndarray, b: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of the density exp(-x'Qx/2 + b'x) on the box
    [lo, hi] (2-D), by adaptive quadrature."""
    def dens(x2, x1):
        x = np.array([x1, x2])
        return np.exp(-0.5 * x @ q @ x + b @ x)

    opts = dict(epsabs=1e-12, epsrel=1e-10)
    z = integrate.dblquad(dens, lo[0], hi[0], lo[1], hi[1], **opts)[0]
    mom = {}
    for key, f in {"1": lambda u, v: v, "2": lambda u, v: u, "11": lambda u, v: v * v,
                   "22": lambda u, v: u * u, "12": lambda u, v: u * v}.items():
        mom[key] = integrate.dblquad(lambda u, v: f(u, v) * dens(u, v), lo[0], hi[0],
                                     lo[1], hi[1], **opts)[0] / z
    mean = np.array([mom["1"], mom["2"]])
    cov = np.array([[mom["11"], mom["12"]], [mom["12"], mom["22"]]]) - np.outer(mean, mean)
    return mean, cov
