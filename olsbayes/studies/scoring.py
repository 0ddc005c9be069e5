"""Scores of an estimate against the truth in CRLB units, batched over trials.

Sources are exchangeable, so each estimate is matched to the truth by the
permutation of its sources with the least squared (wrapped) location error
before any error is measured.
"""

from __future__ import annotations

import numpy as np

from ..bounds import bound_covariance, kink_sources
from ..circular import wrap_angle
from ..exchange import match_sources
from ..model import Model

__all__ = ["score", "ring_truth", "SCORE_NAMES"]

#: Names returned by :func:`score`.
SCORE_NAMES = ("dir_err_rms", "dir_crlb_rms", "dir_z2", "int_z2", "max_z", "resolvable",
               "on_kink")


def _loc_err(model: Model, est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    d = est - truth
    if model.kind != "position":
        d = d.copy()
        d[..., 0] = wrap_angle(d[..., 0])
    return d


def score(model: Model, est: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """Errors of estimates ``est`` (T, P) against ``truth`` (T, P), scaled by the CRLB at truth.

    Returns
    -------
    dict of ndarray (T,)
        ``dir_err_rms`` RMS over sources of the location error (rad for rings);
        ``dir_crlb_rms`` RMS of the CRLB location std; ``dir_z2`` mean over
        sources of (error / CRLB std)^2 of the locations and ``int_z2`` of the
        intensities (inf where unresolvable); ``max_z`` the largest |error| / CRLB
        std over all parameters; ``resolvable`` whether the truth's Fisher matrix
        is regular; ``on_kink`` whether a source sits on the kink of the law.
    """
    est, truth = np.atleast_2d(est), np.atleast_2d(truth)
    k, w = model.n_sources_of(truth), model.n_loc + 1
    matched = match_sources(model, est, truth)
    err = _loc_err(model, matched.reshape(-1, k, w), truth.reshape(-1, k, w))
    err[..., -1] = matched.reshape(-1, k, w)[..., -1] - truth.reshape(-1, k, w)[..., -1]
    fisher = model.fisher(truth)
    cov, _, singular = bound_covariance(fisher)  # batched over the trials
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1)).reshape(-1, k, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(np.isfinite(std), err / std, np.inf)
    loc = err[..., :-1]
    return {
        "dir_err_rms": np.sqrt(np.mean(loc**2, axis=(-1, -2))),
        "dir_crlb_rms": np.sqrt(np.mean(std[..., :-1] ** 2, axis=(-1, -2))),
        "dir_z2": np.mean(z[..., :-1] ** 2, axis=(-1, -2)),
        "int_z2": np.mean(z[..., -1] ** 2, axis=-1),
        "max_z": np.max(np.abs(z), axis=(-1, -2)),
        "resolvable": ~singular.any(axis=-1),
        "on_kink": np.any(kink_sources(model, truth), axis=-1),
    }


def ring_truth(model: Model, settings: dict, *, rng: np.random.Generator) -> np.ndarray:
    """One ring scene (2K,) for a trial.

    The first source is uniform on the circle -- or, with ``kink = True``, exactly
    90 deg from a random sub-sensor (on the kink of the clipped cosine) -- and
    source k sits ``k * separation`` rad further on (default 2 pi / ``slots``,
    ``slots`` default K: evenly spread); all have intensity ``intensity`` (default 1).
    Note: three equal sources evenly spread are nearly unidentifiable under the
    clipped cosine -- only its Fourier harmonics 0, 6, 12, ... survive the sum --
    so use e.g. ``slots = 4`` for a generic three-source scene.
    """
    k = int(settings.get("n_sources", 1))
    sep = float(settings.get("separation", 2 * np.pi / int(settings.get("slots", k))))
    if settings.get("kink", False):
        normals = model.array.normals
        j = int(rng.integers(model.n_sensors))
        theta0 = float(np.arctan2(normals[j, 1], normals[j, 0])) + np.pi / 2
    else:
        theta0 = float(rng.uniform(-np.pi, np.pi))
    theta = wrap_angle(theta0 + sep * np.arange(k))
    inten = np.full(k, float(settings.get("intensity", 1.0)))
    return np.column_stack([theta, inten]).ravel()
