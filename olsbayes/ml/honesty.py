"""Warnings that keep an ML result honest: missing standard errors and a poor fit.

Two things a converged fit can still get wrong, each warned about by
:func:`olsbayes.ml.fit_ml` (they never change a number):

* **No standard error.**  Where the Fisher matrix at the estimate is singular
  (a source at intensity 0 has no direction, two sources closer than the array
  resolves trade intensity, K (d + 1) = N readings leave nothing over) some
  parameters have an infinite CRLB; where it overflowed, a NaN one.
  :class:`~olsbayes.errors.ResolutionWarning` names them.
* **Goodness of fit.**  At the ML estimate of a correct model, chi^2 / sigma^2 =
  sum (s - mu)^2 / sigma^2 follows a chi-squared law of N - P degrees of freedom
  (asymptotically; P fitted parameters).  A value in either tail beyond
  :data:`GOF_ALPHA` (two-sided, Bonferroni-corrected over the rows of a batch) means
  the readings are not K sources plus noise of this sigma: too large -- more
  sources, another sensitivity law or sigma, or a fit that missed the global
  optimum; too small -- sigma overestimated.  The standard errors assume the
  model holds, so :class:`~olsbayes.errors.ConvergenceWarning` says so.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from ..errors import ConvergenceWarning, ResolutionWarning
from ..model import Model
from ..resolution import (
    RESOLUTION_SPACINGS,
    WEAK_SDS,
    min_separation,
    warn_gaussian_doubts,
)

__all__ = ["warn_honesty", "gof_pvalues", "GOF_ALPHA"]

#: Two-sided level of the goodness-of-fit test, for the whole batch of rows.
GOF_ALPHA = 1e-3


def gof_pvalues(model: Model, log_likelihood: np.ndarray, n_params: int
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """chi^2 / sigma^2 (T,), its two-sided p-values (T,) and the degrees of freedom N - P.

    The p-values are NaN when N - P < 1 (no readings left over for the noise).
    """
    from scipy.special import chdtr, chdtrc  # the chi-squared cdf and sf, as ufuncs

    z, dof = _chi2_sigma2(model, log_likelihood), model.n_sensors - n_params
    if dof < 1:
        return z, np.full(z.shape, np.nan), dof
    p = 2.0 * np.minimum(chdtr(dof, z), chdtrc(dof, z))
    return z, np.minimum(p, 1.0), dof


def _warn_std(model: Model, x: np.ndarray, cov: np.ndarray, method: str) -> None:
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    bad = ~np.isfinite(std)
    rows = np.flatnonzero(bad.any(axis=-1))
    if rows.size == 0:
        return
    names = model.param_names(model.n_sources_of(x))
    first = [n for n, b in zip(names, bad[rows[0]]) if b]
    first = first[:6] + (["..."] if len(first) > 6 else [])
    nan = bool(np.isnan(std[rows]).any())
    warnings.warn(
        f"{rows.size} of {x.shape[0]} ML fit(s) ({method}) have no finite standard error for "
        f"some parameters (first: {', '.join(first)}): the Fisher matrix at the estimate is "
        + ("not finite (intensity / sigma too large to represent)" if nan else
           "singular -- a source at intensity 0 has no direction, sources closer than the "
           "array resolves trade intensity, or K (d + 1) parameters leave no reading over")
        + "; MLResult.std holds inf/NaN there and the other errors are conditional on them",
        ResolutionWarning,
        stacklevel=5,
    )


def _chi2_sigma2(model: Model, log_likelihood: np.ndarray) -> np.ndarray:
    """chi^2 / sigma^2 from Gaussian log-likelihoods (clipped at 0 against rounding)."""
    const = model.n_sensors * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
    return np.maximum(-2.0 * (np.asarray(log_likelihood, dtype=float) + const), 0.0)


@functools.lru_cache(maxsize=256)
def _gof_band(dof: int, alpha: float) -> tuple[float, float]:
    """An interval of chi^2 / sigma^2 whose two-sided p-values all exceed ``alpha``.

    The alpha/2 quantiles of the chi-squared law of ``dof`` degrees of freedom,
    narrowed by a relative 1e-6 (far beyond the quantiles' rounding): values
    inside need no p-value, values outside get the exact test.
    """
    from scipy.special import chdtri, gammaincinv  # inverse survival function and cdf

    # the lower quantile from the cdf itself: 1 - alpha / 2 would round for tiny alpha
    lo, hi = 2.0 * gammaincinv(dof / 2, alpha / 2), chdtri(dof, alpha / 2)
    return float(lo) * (1 + 1e-6), float(hi) * (1 - 1e-6)


def _warn_fit(model: Model, ll: np.ndarray, p: int, method: str) -> None:
    if model.n_sensors - p >= 1:  # else no p-value: nothing to test
        lo, hi = _gof_band(model.n_sensors - p, GOF_ALPHA / ll.size)
        z = _chi2_sigma2(model, ll)
        if z.min() > lo and z.max() < hi:
            return  # every row well inside the law's central 1 - alpha
    z, pval, dof = gof_pvalues(model, ll, p)
    bad = pval < GOF_ALPHA / ll.size
    if not np.any(bad):
        return
    worst = int(np.flatnonzero(bad)[np.argmin(pval[bad])])
    ratio = z[worst] / dof
    side = ("more sources than K, another sigma or sensitivity law, or a fit that missed "
            "the global optimum" if ratio > 1 else "sigma overestimated")
    warnings.warn(
        f"{int(bad.sum())} of {ll.size} ML fit(s) ({method}) do not describe the readings: "
        f"chi^2/(N-P) = {ratio:.3g} with N-P = {dof} (expected 1 +- {np.sqrt(2 / dof):.2g}; "
        f"two-sided p = {pval[worst]:.2g} under sigma = {model.sigma:g}"
        + (f", below {GOF_ALPHA:g}/{ll.size} for the batch" if ll.size > 1 else "")
        + f"): {side}; the standard errors assume K sources and this sigma",
        ConvergenceWarning,
        stacklevel=5,
    )


def warn_honesty(model: Model, x: np.ndarray, ll: np.ndarray, cov: np.ndarray,
                 method: str) -> None:
    """Warn about missing standard errors and poor fits of a batch of ML results.

    ``x`` (T, P), ``ll`` (T,), ``cov`` (T, P, P): the estimates, log-likelihoods and
    inverse Fisher matrices of a fit.  Called from :func:`olsbayes.ml.fit_ml` (whose
    caller is the warning's location).
    """
    doubt, no_std = _doubts(model, x, cov)
    if no_std.any():
        _warn_std(model, x, cov, method)
    _warn_fit(model, ll, x.shape[-1], method)
    warn_gaussian_doubts(model, x, cov, method, stacklevel=4, doubt=doubt)


def _doubts(model: Model, x: np.ndarray, cov: np.ndarray
            ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Gaussian doubts of x (T, P) and cov (T, P, P); rows without a finite sd, bool (T,).

    The doubts are those of :func:`~olsbayes.resolution.gaussian_doubts`: the tests
    of the covariances compiled (the same flags,
    :func:`olsbayes.ml._numba.resolution.covariance_doubts`), the separations in numpy.
    """
    from ._numba.resolution import covariance_doubts  # numba is imported on first use

    finite, weak, no_std = covariance_doubts(x, cov, model.n_loc + 1, WEAK_SDS)
    sep = min_separation(model, x)
    return {"close": finite & (sep < RESOLUTION_SPACINGS), "weak": finite & weak,
            "separation": sep}, no_std
