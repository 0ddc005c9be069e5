"""Compiled (numba) statistics of a fit's result: twin of :mod:`olsbayes.ml.fit`.

The residual sum of squares and the Fisher matrix at the estimates in one pass,
and their inverses by the rule of :func:`olsbayes.bounds.bound_covariance`: the
compiled counterparts of ``Model.log_likelihood``/``Model.fisher`` and
``bound_covariance``, equal to rounding.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...model import Model
from . import kernel_array
from .lm import _arrays, _normal_eq
from .model import _residual

__all__ = ["chi2_fisher", "covariances"]

@numba.njit(cache=True)
def _stats_all(kind, law, p, nrm, pos, x, data, chi2, fisher):  # pragma: no cover
    """chi^2 of every row of x (T, P) against data (T, N) and J^T J (T, P, P)."""
    t, np_ = x.shape
    jt, r, g = np.empty((np_, data.shape[1])), np.empty(data.shape[1]), np.empty(np_)
    for i in range(t):
        chi2[i] = _residual(kind, law, p, nrm, pos, x[i], data[i], jt, r, True)
        _normal_eq(jt, r, fisher[i], g)


def chi2_fisher(model: Model, x: np.ndarray, data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum of squared residuals (T,) and Fisher information J^T J / sigma^2 (T, P, P).

    For a supported model, x (T, P) and data (T, N); the compiled counterpart of
    ``model.log_likelihood`` and ``model.fisher`` (rounding-level differences).
    """
    kind, code, p, nrm, pos = _arrays(model)
    xx, s = kernel_array(x, np.float64), kernel_array(data, np.float64)
    chi2, fisher = np.empty(xx.shape[0]), np.empty((xx.shape[0],) + (xx.shape[1],) * 2)
    _stats_all(kind, code, p, nrm, pos, xx, s, chi2, fisher)
    fisher /= model.sigma**2
    return chi2, fisher


@numba.njit(cache=True)
def _chol_inverse(f, lw, out, rtol):  # pragma: no cover - compiled
    """out = f^-1 by Cholesky if f is provably regular under the rule, else False.

    lambda_min >= 1 / trace(f^-1) and lambda_max <= trace(f), so
    rtol * trace(f) * trace(f^-1) < 0.5 means no eigenvalue is <= rtol * lambda_max
    (with a factor 2 to spare for rounding): the pseudo-inverse is the inverse.
    """
    p = f.shape[0]
    tr = 0.0
    for c in range(p):  # lw: L (lower), then L^-1 in place
        tr += f[c, c]
        d = f[c, c]
        for k in range(c):
            d -= lw[c, k] * lw[c, k]
        if not d > 0.0:
            return False
        lw[c, c] = math.sqrt(d)
        for i in range(c + 1, p):
            v = f[i, c]
            for k in range(c):
                v -= lw[i, k] * lw[c, k]
            lw[i, c] = v / lw[c, c]
    for c in range(p):
        lw[c, c] = 1.0 / lw[c, c]
        for i in range(c + 1, p):
            acc = 0.0
            for k in range(c, i):
                acc += lw[i, k] * lw[k, c]
            lw[i, c] = -acc / lw[i, i]
    tr_inv = 0.0
    for a in range(p):  # f^-1 = L^-T L^-1
        for b in range(a + 1):
            acc = 0.0
            for k in range(a, p):
                acc += lw[k, a] * lw[k, b]
            out[a, b] = acc
            out[b, a] = acc
        tr_inv += out[a, a]
    return rtol * tr * tr_inv < 0.5


@numba.njit(cache=True)
def _cov_all(fisher, rtol, out):  # pragma: no cover - compiled
    """Pseudo-inverse of each Fisher matrix with null-space rows/columns set to inf.

    A provably regular matrix is inverted by Cholesky (:func:`_chol_inverse`; the
    same matrix to rounding, far cheaper than the eigendecomposition).
    """
    t, p = fisher.shape[:2]
    null, singular = np.empty(p, np.bool_), np.empty(p, np.bool_)
    lw = np.zeros((p, p))
    for i in range(t):
        if _chol_inverse(fisher[i], lw, out[i], rtol):
            continue
        w, v = np.linalg.eigh(fisher[i])
        top = max(w[p - 1], 2.2250738585072014e-308)
        for j in range(p):
            null[j] = w[j] <= rtol * top
        for a in range(p):
            singular[a] = False
            for j in range(p):
                singular[a] = singular[a] or (null[j] and abs(v[a, j]) > 1e-6)
        for a in range(p):
            for b in range(p):
                acc = 0.0
                for j in range(p):
                    if not null[j]:
                        acc += v[a, j] * (1.0 / w[j]) * v[b, j]
                out[i, a, b] = np.inf if singular[a] or singular[b] else acc


@numba.njit(cache=True)
def _cov_equilibrated(fisher, rtol, out):  # pragma: no cover - compiled
    """:func:`_cov_all` of the equilibrated matrices D F D, scaled back: D (D F D)^+ D.

    D = diag(d), d = diag(F)^-1/2 (1 where a diagonal is not > 0), every product
    taken in the order of :func:`olsbayes.bounds.equilibrate` and of the numpy
    scaling, so the numbers are those of equilibrating in numpy.
    """
    t, p = fisher.shape[:2]
    d, f = np.empty((t, p)), np.empty((t, p, p))
    for i in range(t):
        for a in range(p):
            v = fisher[i, a, a]
            d[i, a] = 1.0 / math.sqrt(v) if v > 0.0 else 1.0
        for a in range(p):
            for b in range(p):
                f[i, a, b] = fisher[i, a, b] * d[i, a] * d[i, b]
    _cov_all(f, rtol, out)
    for i in range(t):
        for a in range(p):
            for b in range(p):
                out[i, a, b] = out[i, a, b] * d[i, a] * d[i, b]


def covariances(fisher: np.ndarray, rtol: float) -> np.ndarray:
    """Inverse Fisher matrices (T, P, P) by the rule of :func:`olsbayes.bounds.bound_covariance`.

    For finite input.  The kernel works on the equilibrated matrices
    (:func:`olsbayes.bounds.equilibrate`, compiled alike).
    """
    f = kernel_array(fisher, np.float64)
    out = np.empty(f.shape)
    _cov_equilibrated(f, float(rtol), out)
    return out
