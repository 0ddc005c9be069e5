"""Compiled (numba) circular arithmetic: twin of :mod:`olsbayes.circular`."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["wrap"]

_TWO_PI = 2.0 * np.pi


@numba.njit(cache=True)
def wrap(a):  # pragma: no cover - compiled
    """Angle wrapped to (-pi, pi] (circular.wrap_angle)."""
    w = a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)
    return math.pi if w == -math.pi else w
