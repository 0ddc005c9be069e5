"""Compiled (numba) kink moves of the fast fit: twin of :mod:`olsbayes.ml.fast.refine`.

Kink-hop starts (:func:`olsbayes.ml.fast.refine.hop_starts`, identical output) and
the test for sources on a sub-sensor's horizon (:func:`olsbayes.bounds.kink_sources`
for a kinked law), each a single compiled call instead of a dozen small numpy calls.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...model import Model
from . import kernel_array
from .lm import _arrays

__all__ = ["hop_starts", "on_kink"]

_TWO_PI = 2.0 * np.pi


@numba.njit(cache=True)
def _hops(cross, x, eps, out):  # pragma: no cover - compiled
    """Kink-hop starts (T, 2K, P) of angle fits x (T, P); see refine.hop_starts."""
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
                    m = y  # subtraction or none (the same bits, cheaper)
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
    """Compiled :func:`olsbayes.ml.fast.refine.hop_starts` (identical output)."""
    def make() -> np.ndarray:
        nrm = model.array.normals
        phi = np.arctan2(nrm[:, 1], nrm[:, 0])
        return np.concatenate([phi + np.pi / 2, phi - np.pi / 2])

    cross = model.memo("hop_crossings", make)
    xx = kernel_array(x, np.float64)
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
    xx = kernel_array(x, np.float64)
    out = np.empty((xx.shape[0], xx.shape[1] // (kind + 2)), np.bool_)
    _kinked(kind, nrm, pos, xx, float(atol), out)
    return out
