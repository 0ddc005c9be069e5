"""Validation of the arguments every ML method shares (the model, the data, K)."""

from __future__ import annotations

import numpy as np

from .._validation import integer
from ..errors import InputError
from ..model import Model

__all__ = ["check_fit_inputs"]


def check_fit_inputs(model: object, data: object, n_sources: object) -> tuple[np.ndarray, int]:
    """Validated readings (N,) or (T, N) and number of sources K.

    Raises
    ------
    InputError
        ``model`` not a :class:`~olsbayes.Model`; ``data`` not finite, not of last
        axis N or more than 2-D; K outside [1, N // (d + 1)].
    """
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    arr = model.check_data(data)
    if arr.ndim not in (1, 2):
        raise InputError(
            f"data must have shape (N,) or (T, N) with N = {model.n_sensors}; got {arr.shape}"
        )
    k_max = model.n_sensors // (model.n_loc + 1)
    k = integer("n_sources", n_sources, low=1, high=max(k_max, 1))
    if model.n_params(k) > model.n_sensors:
        raise InputError(
            f"n_sources must be in [1, {k_max}] (K * {model.n_loc + 1} parameters must not "
            f"exceed N = {model.n_sensors} readings); got {k}"
        )
    return arr, k
