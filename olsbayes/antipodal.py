r"""Near-antipodal source pairs on a ring: a direction the readings barely constrain.

On a ring whose sub-sensors come in opposite pairs (an even number N of them),
the clipped cosine satisfies ``max(c, 0) - max(-c, 0) = c``, so the difference
of two opposite readings is a single cosine of the sensor angle alpha:

.. math::

    s(\alpha) - s(\alpha + \pi) = \sum_k I_k \cos(\theta_k - \alpha)
    = A \cos \alpha + B \sin \alpha ,

with ``A + iB = sum_k I_k exp(i theta_k)``: half the readings' information is
one complex number, the resultant of the sources.  Two sources a and b with
``b = a + pi + delta`` contribute ``(I_a - I_b e^{i delta}) e^{i a}`` to it,
which for small delta is nearly unchanged when the pair is replaced by its
*mirror* ``(b - pi, a + pi)`` -- each source moved to the antipode of the
other, the offset ``delta`` reversed -- with adjusted intensities; the sums
``s(alpha) + s(alpha + pi) = sum_k I_k |cos(theta_k - alpha)|`` change only
near the sub-sensors' horizons.  So a pair within a couple of sensor spacings
``2 pi / N`` of antipodal leaves the likelihood with (almost) equally good
mirrored optima, or a valley joining them: the local Fisher matrix (the CRLB)
then describes one optimum, not the posterior, and an ML estimate may sit in
either.  With several such pairs the optima multiply (2 per pair).

:func:`antipodal_pairs` finds such pairs in a ring scene; :func:`mirror_pair`
builds the mirrored configuration, a starting point for a mode search
(:mod:`olsbayes.posterior.modes`).
"""

from __future__ import annotations

import functools

import numpy as np

from ._validation import positive_float
from .circular import wrap_angle

__all__ = ["antipodal_pairs", "pair_offsets", "source_pairs", "mirror_pair",
           "ANTIPODAL_SPACINGS"]

#: Pairs within this many sensor spacings of antipodal are reported by default.
ANTIPODAL_SPACINGS = 2.0


@functools.lru_cache(maxsize=64)
def source_pairs(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays (i, j) of the K (K - 1) / 2 source pairs i < j, row by row (read-only)."""
    i, j = np.triu_indices(k, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def pair_offsets(model, x: np.ndarray) -> np.ndarray:
    """Each ring source pair's offset from antipodal, in sensor spacings: (T, K (K - 1) / 2).

    ``x`` (T, P): ring estimates in the flat layout (angles in rad); pairs in the
    order of :func:`source_pairs`.  The offset of pair (i, j) is
    ``wrap(theta_j - theta_i - pi) / (2 pi / N)``, as :func:`antipodal_pairs` gives it.
    """
    theta = x[:, 0 :: model.n_loc + 1]
    i, j = source_pairs(theta.shape[1])
    return wrap_angle(theta[:, j] - theta[:, i] - np.pi) / (2.0 * np.pi / model.n_sensors)


def antipodal_pairs(model, params: np.ndarray, *, within: float = ANTIPODAL_SPACINGS
                    ) -> tuple[tuple[int, int, float], ...]:
    """Pairs of ring sources less than ``within`` sensor spacings from antipodal.

    Parameters
    ----------
    model : Model
        A ring model (``kind == "angle"``); other kinds have no pairs (empty tuple).
    params : ndarray (K (d + 1),)
        One scene in the model's flat layout (angles in rad).
    within : float
        Threshold in sensor spacings ``2 pi / N`` (> 0).

    Returns
    -------
    tuple of (i, j, offset)
        Source indices i < j and ``offset = wrap(theta_j - theta_i - pi)`` in
        sensor spacings (signed), ordered by ``|offset|``.
    """
    within = positive_float("within", within)
    if model.kind != "angle":
        return ()
    x = np.asarray(params, dtype=float)
    k = model.n_sources_of(x)
    theta = x.reshape(k, -1)[:, 0]
    spacing = 2.0 * np.pi / model.n_sensors
    out = []
    for i in range(k):
        for j in range(i + 1, k):
            offset = float(wrap_angle(theta[j] - theta[i] - np.pi)) / spacing
            if abs(offset) < within:
                out.append((i, j, offset))
    return tuple(sorted(out, key=lambda p: abs(p[2])))


def mirror_pair(params: np.ndarray, i: int, j: int, width: int) -> np.ndarray:
    """The scene with sources i and j replaced by their mirror ``(b - pi, a + pi)``.

    ``params`` (P,) in a flat layout whose sources have ``width`` entries, the
    angle first (a ring: width 2); intensities are kept (a local fit adjusts them).
    """
    y = np.array(params, dtype=float)
    a, b = y[i * width], y[j * width]
    y[i * width] = wrap_angle(b - np.pi)
    y[j * width] = wrap_angle(a + np.pi)
    return y
