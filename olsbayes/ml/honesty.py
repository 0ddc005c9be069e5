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

import warnings

import numpy as np

from ..errors import ConvergenceWarning, ResolutionWarning
from ..model import Model
from ..resolution import warn_gaussian_doubts

__all__ = ["warn_honesty", "gof_pvalues", "GOF_ALPHA"]

#: Two-sided level of the goodness-of-fit test, for the whole batch of rows.
GOF_ALPHA = 1e-3


def gof_pvalues(model: Model, log_likelihood: np.ndarray, n_params: int
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """chi^2 / sigma^2 (T,), its two-sided p-values (T,) and the degrees of freedom N - P.

    The p-values are NaN when N - P < 1 (no readings left over for the noise).
    """
    from scipy.special import chdtr, chdtrc  # the chi-squared cdf and sf, as ufuncs

    n = model.n_sensors
    const = n * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
    z = np.maximum(-2.0 * (np.asarray(log_likelihood, dtype=float) + const), 0.0)
    dof = n - n_params
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


def _warn_fit(model: Model, ll: np.ndarray, p: int, method: str) -> None:
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
    _warn_std(model, x, cov, method)
    _warn_fit(model, ll, x.shape[-1], method)
    warn_gaussian_doubts(model, x, cov, method, stacklevel=4)
