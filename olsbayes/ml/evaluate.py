"""Scoring estimates against a known truth (simulation studies)."""

from __future__ import annotations

import itertools

import numpy as np

from ..errors import InputError
from ..geometry import wrap_angle
from ..model import Model

__all__ = ["estimation_errors"]


def estimation_errors(model: Model, params: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Errors ``params - truth`` after matching estimated to true sources.

    Sources are exchangeable, so each estimate's sources are permuted to the
    assignment that minimises the summed squared location error (angles
    wrapped) -- sorting by angle alone mislabels fits whose weak source wanders
    past a strong one.  Exhaustive over the K! permutations (K <= 6).

    Parameters
    ----------
    model : Model
    params : ndarray, shape (..., P)
        Estimates in the model's flat layout.
    truth : ndarray, shape (P,) or (..., P)
        One truth, or one per estimate (leading axes broadcast against params').

    Returns
    -------
    ndarray, shape (..., P)
        Errors in the layout (and source order) of ``truth``; angle errors wrapped
        to (-pi, pi].
    """
    est = np.asarray(params, dtype=float)
    tru = np.asarray(truth, dtype=float)
    k = model.n_sources_of(tru)
    if est.shape[-1] != tru.shape[-1] or k > 6:
        raise InputError(
            f"params must have last axis {tru.shape[-1]} like truth, with K <= 6; "
            f"got shapes {est.shape} and {tru.shape}"
        )
    d1 = model.n_loc + 1
    e_blk = est.reshape(est.shape[:-1] + (k, d1))
    t_blk = tru.reshape(tru.shape[:-1] + (k, d1))
    best_err, best_cost = None, None
    for perm in itertools.permutations(range(k)):
        err = e_blk[..., list(perm), :] - t_blk
        if model.kind != "position":
            err[..., 0] = wrap_angle(err[..., 0])
        cost = np.sum(err[..., :-1] ** 2, axis=(-1, -2))
        if best_cost is None:
            best_err, best_cost = err, cost
        else:
            better = cost < best_cost
            best_err = np.where(better[..., None, None], err, best_err)
            best_cost = np.minimum(cost, best_cost)
    return best_err.reshape(np.broadcast_shapes(est.shape, tru.shape))
