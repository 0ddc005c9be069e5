"""Compiled (numba) pieces of a fast fit around the LM and the search.

For a single data vector the fit's bookkeeping -- kink hops, kink tests, the
result's log-likelihood, Fisher matrix and covariance -- is a few dozen small
numpy calls; compiled, each is a single call.  Same formulas as the numpy
code they replace (``fast.hop_starts``, ``bounds.kink_sources``,
``Model.log_likelihood``/``Model.fisher`` and ``api._covariances``), equal to
rounding (``hop_starts`` exactly).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..bounds import equilibrate
from ..model import Model
from ._kernel import _arrays, _normal_eq
from ._model_kernel import _residual

__all__ = ["chi2_fisher", "covariances", "hop_starts", "on_kink"]

_TWO_PI = 2.0 * np.pi


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
    xx = np.require(x, np.float64, ["C", "W"])
    s = np.require(data, np.float64, ["C", "W"])
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
    same matrix to rounding, ~20x cheaper than the eigendecomposition).
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


def covariances(fisher: np.ndarray, rtol: float) -> np.ndarray:
    """Inverse Fisher matrices (T, P, P) by the rule of ``api._covariances`` (finite
    input): the kernel works on the equilibrated matrices (:func:`olsbayes.bounds.equilibrate`)."""
    f, d = equilibrate(np.asarray(fisher, dtype=np.float64))
    f = np.require(f, np.float64, ["C", "W"])
    out = np.empty(f.shape)
    _cov_all(f, float(rtol), out)
    return out * d[:, :, None] * d[:, None, :]


@numba.njit(cache=True)
def _hops(cross, x, eps, out):  # pragma: no cover - compiled
    """Kink-hop starts (T, 2K, P) of angle fits x (T, P); see fast.hop_starts."""
    t, p = x.shape
    for i in range(t):
        for h in range(p):
            out[i, h, :] = x[i]
        for j in range(p // 2):
            th = x[i, 2 * j]
            up, down = np.inf, -np.inf
            for c in cross:
                y = np.pi - (c - th)  # circular.wrap_angle: d = pi - y % 2 pi; the
                if 0.0 <= y < _TWO_PI:  # float modulo done by hand where it is one
                    m = y  # subtraction or none (the same bits, ~10x cheaper)
                elif -_TWO_PI <= y < 0.0:
                    m = y + _TWO_PI
                else:
                    m = y % _TWO_PI
                d = np.pi - m
                if d > 1e-9 and d < up:
                    up = d
                if d < -1e-9 and d > down:
                    down = d
            out[i, 2 * j, 2 * j] = th + (up + eps)
            out[i, 2 * j + 1, 2 * j] = th + (down - eps)


def hop_starts(model: Model, x: np.ndarray) -> np.ndarray:
    """Compiled :func:`olsbayes.ml.fast.hop_starts` (identical output)."""
    def make() -> np.ndarray:
        nrm = model.array.normals
        phi = np.arctan2(nrm[:, 1], nrm[:, 0])
        return np.concatenate([phi + np.pi / 2, phi - np.pi / 2])

    cross = model.memo("hop_crossings", make)
    xx = np.require(x, np.float64, ["C", "W"])
    out = np.empty((xx.shape[0], xx.shape[1], xx.shape[1]))
    _hops(cross, xx, 0.05 * np.pi / model.n_sensors, out)
    return out


@numba.njit(cache=True)
def _kinked(kind, nrm, pos, x, atol, out):  # pragma: no cover - compiled
    """out[i, k]: some sensor sees source k of x[i] at |cos| < atol (crlb.kink_sources)."""
    d1 = kind + 2
    n_s = nrm.shape[1]
    for i in range(x.shape[0]):
        for k in range(x.shape[1] // d1):
            b = k * d1
            u0, u1, u2 = 0.0, 0.0, 0.0
            if kind == 0:
                u0, u1 = math.cos(x[i, b]), math.sin(x[i, b])
            elif kind == 1:
                cla = math.cos(x[i, b + 1])
                u0, u1, u2 = cla * math.cos(x[i, b]), cla * math.sin(x[i, b]), math.sin(x[i, b + 1])
            hit = False
            for n in range(n_s):
                if kind == 2:
                    e0, e1 = x[i, b] - pos[0, n], x[i, b + 1] - pos[1, n]
                    e2 = x[i, b + 2] - pos[2, n]
                    c = (e0 * nrm[0, n] + e1 * nrm[1, n] + e2 * nrm[2, n]) / math.sqrt(
                        e0 * e0 + e1 * e1 + e2 * e2)
                elif kind == 0:
                    c = u0 * nrm[0, n] + u1 * nrm[1, n]
                else:
                    c = u0 * nrm[0, n] + u1 * nrm[1, n] + u2 * nrm[2, n]
                hit = hit or abs(c) < atol
            out[i, k] = hit


def on_kink(model: Model, x: np.ndarray, atol: float) -> np.ndarray:
    """Compiled ``bounds.kink_sources`` for a kinked law: bool (T, K)."""
    kind, _, _, nrm, pos = _arrays(model)
    xx = np.require(x, np.float64, ["C", "W"])
    out = np.empty((xx.shape[0], xx.shape[1] // (kind + 2)), np.bool_)
    _kinked(kind, nrm, pos, xx, float(atol), out)
    return out
