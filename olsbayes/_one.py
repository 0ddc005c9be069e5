"""One far-field parameter vector: Eq. 1, its Jacobian and the Gaussian log-likelihood.

User loops, per-walker samplers and scipy optimisers call the model on one
vector (P,) at a time, where the batched kernel's bookkeeping (batch shapes,
blocks, broadcasting checks) costs more than the arithmetic.  The functions here
run the batched paths' operations on a batch of one, on arrays of the same
layout, without that bookkeeping: their results equal the batched ones to the
bit.  The caller (:class:`~olsbayes.Model`) has validated ``x`` (a float64
vector whose length is a multiple of d + 1) and chooses these paths only for
far-field sources (ring angles, sphere directions).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .geometry import lonlat_to_unit

if TYPE_CHECKING:  # pragma: no cover
    from .model import Model

__all__ = ["response", "jacobian_t", "log_likelihood", "sum_squares", "sum_products"]

try:  # numpy's einsum kernel without its Python wrapper (the same kernel, the same bits)
    from numpy._core.multiarray import c_einsum as sum_products
except ImportError:  # pragma: no cover - numpy 1.x layout, or none: the wrapper itself
    try:
        from numpy.core.multiarray import c_einsum as sum_products
    except ImportError:
        sum_products = np.einsum


def sum_squares(r: np.ndarray) -> np.ndarray:
    """``sum_n r[..., n]^2``, shape (...,): ``np.einsum("...n,...n->...", r, r)`` exactly."""
    return sum_products("...n,...n->...", r, r)


def response(model: Model, x: np.ndarray) -> np.ndarray:
    """Noiseless readings (N,) of one vector x (P,), a fresh array.

    Unit vectors (K, D), ``g(u n^T)`` (K, N), each row times its intensity, then
    the K rows summed in source order (elementwise products and sums: the same
    roundings as the batched kernel's).
    """
    d1 = model._d1
    k = x.shape[0] // d1
    if k == 0:
        return np.zeros(model._n_sensors)
    if d1 == 2:  # ring angles, as Model._units computes their unit vectors
        th, u = x[0::2], np.empty((k, 2))
        np.cos(th, u[:, 0])
        np.sin(th, u[:, 1])
    else:
        u = lonlat_to_unit(x[0::3], x[1::3])
    c = np.dot(u, model._normals_t)
    if not model._clipped:
        terms = np.multiply(model.sensitivity.value(c), x.reshape(k, d1)[:, -1:])
        out = terms[0]
        for j in range(1, k):
            np.add(out, terms[j], out)
        return out
    g = np.maximum(c, 0.0, out=c)  # the clipped cosine, in place
    if k == 1:
        row = g[0]
        return np.multiply(row, x[d1 - 1], row)
    return sum_products("k,kn->n", x[d1 - 1::d1], g)  # the batched kernel's sum, same order


def jacobian_t(model: Model, x: np.ndarray) -> np.ndarray:
    """Transposed Jacobian (P, N), C-contiguous, of one vector x (P,).

    Row ``(d + 1) k + j`` is ``I_k g'(c_k) dc_k / dloc_j`` for the location
    parameters and ``g(c_k)`` for the intensity, ``c_k = u_k . n``.
    """
    d1, n = model._n_loc + 1, model._n_sensors
    k = x.shape[0] // d1
    blocks = x.reshape(k, d1)
    if d1 == 2:  # ring angles, as Model._directions computes them
        th, u = x[0::2], np.empty((k, 2))
        np.cos(th, u[:, 0])
        np.sin(th, u[:, 1])
        tang = np.empty((k, 1, 2))
        np.negative(u[:, 1], tang[:, 0, 0])
        tang[:, 0, 1] = u[:, 0]
    else:
        u, tang = model._directions(blocks[:, :-1])
    c = u @ model._normals_t  # (K, N)
    out = np.empty((k, d1, n))
    if model._clipped:  # g = max(c, 0) straight into its rows, g' = [c > 0]
        np.maximum(c, 0.0, out=out[:, -1, :])
        slope = blocks[:, -1:] * np.greater(c, 0.0)
    else:
        law = model.sensitivity
        out[:, -1, :] = law.value(c)
        slope = blocks[:, -1:] * law.derivative(c)
    np.multiply(slope[:, None, :], tang @ model._normals_t, out[:, :-1, :])
    return out.reshape(k * d1, n)


def log_likelihood(model: Model, x: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Gaussian known-sigma log-likelihood (a 0-d value) of one vector x and readings (N,)."""
    mu = response(model, x)  # a fresh array: the residual overwrites it
    resid = np.subtract(data, mu, out=mu)
    return -0.5 * (sum_squares(resid) / model._var) - model._log_norm
