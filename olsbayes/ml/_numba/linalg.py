"""Small dense solves for the compiled LM (:mod:`.lm`) and search (:mod:`.search`) kernels.

Pivoted LU and Cholesky (with the LU as fallback) on P x P systems, P <= ~16,
written out for the small sizes of these kernels.
"""

from __future__ import annotations

import math

import numba

__all__: list[str] = []


@numba.njit(cache=True)
def _solve(m, b, out):  # pragma: no cover - compiled
    """out = m^-1 b by LU with partial pivoting (m is overwritten)."""
    n = b.size
    for i in range(n):
        out[i] = b[i]
    for c in range(n):
        piv = c
        for i in range(c + 1, n):
            if abs(m[i, c]) > abs(m[piv, c]):
                piv = i
        if piv != c:
            for j in range(n):
                m[c, j], m[piv, j] = m[piv, j], m[c, j]
            out[c], out[piv] = out[piv], out[c]
        for i in range(c + 1, n):
            f = m[i, c] / m[c, c]
            for j in range(c + 1, n):
                m[i, j] -= f * m[c, j]
            out[i] -= f * out[c]
    for i in range(n - 1, -1, -1):
        acc = out[i]
        for j in range(i + 1, n):
            acc -= m[i, j] * out[j]
        out[i] = acc / m[i, i]


@numba.njit(cache=True)
def _solve_spd(m, b, out):  # pragma: no cover - compiled
    """out = m^-1 b for a symmetric positive definite m by Cholesky (m overwritten).

    Falls back to :func:`_solve` (pivoted LU, on the intact upper triangle and
    diagonal copy) when rounding makes a pivot non-positive.
    """
    n = b.size
    for c in range(n):
        d = m[c, c]
        for k in range(c):
            d -= m[c, k] * m[c, k]
        if not d > 0.0:  # not numerically SPD: restore the lower triangle, pivot
            for i in range(n):
                for j in range(i):
                    m[i, j] = m[j, i]
            for i in range(c):
                m[i, i] = out[i]  # the saved diagonal (below)
            _solve(m, b, out)
            return
        out[c] = m[c, c]  # save the diagonal for the fallback
        inv = 1.0 / math.sqrt(d)
        m[c, c] = inv  # the diagonal holds 1 / L_cc (multiplications below)
        for i in range(c + 1, n):
            v = m[i, c]
            for k in range(c):
                v -= m[i, k] * m[c, k]
            m[i, c] = v * inv
    for i in range(n):  # forward: L y = b
        acc = b[i]
        for k in range(i):
            acc -= m[i, k] * out[k]
        out[i] = acc * m[i, i]
    for i in range(n - 1, -1, -1):  # backward: L^T x = y
        acc = out[i]
        for k in range(i + 1, n):
            acc -= m[k, i] * out[k]
        out[i] = acc * m[i, i]
