"""When a Laplace evidence is not to be trusted, and why.

The Laplace approximation needs one Gaussian mode per labelling, well inside the
prior's support.  It fails where the Fisher matrix is singular or nearly so
(sources closer than the array resolves: on a ring of even N every pair closer
than one sensor spacing 2 pi/N is unresolvable and only from 2 spacings is every
placement resolvable), where a source is weak (its intensity a few sd from the
prior's edge at 0, its direction barely localised), and where the Gaussian is
wider than the prior.  Each check returns a short human-readable reason.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from .._validation import finite_array, positive_float
from ..antipodal import source_pairs
from ..bounds import bound_covariance
from ..errors import InputError
from ..model import Model
from ..resolution import sensor_spacing, source_distances

__all__ = ["closest_pair", "laplace_trust", "check_thresholds", "THRESHOLDS"]

#: Default thresholds of :func:`laplace_trust` (read-only).
THRESHOLDS: Mapping[str, float] = MappingProxyType({
    "separation": 2.0,  # sensor spacings
    "snr": 5.0,  # intensity / its sd
    "correlation": 0.98,  # largest |correlation| between parameters
})


def check_thresholds(thresholds: Mapping[str, float] | None) -> dict[str, float]:
    """:data:`THRESHOLDS` with the overrides in ``thresholds``, each checked.

    Unknown keys are refused; ``separation`` and ``snr`` must be > 0,
    ``correlation`` in (0, 1].
    """
    if thresholds is None:
        return dict(THRESHOLDS)
    if not isinstance(thresholds, Mapping):
        raise InputError(f"thresholds must be a mapping with keys among {sorted(THRESHOLDS)}; "
                         f"got {type(thresholds).__name__}")
    unknown = sorted(str(key) for key in thresholds if key not in THRESHOLDS)
    if unknown:
        raise InputError(f"thresholds: unknown key(s) {unknown}; the keys are "
                         f"{sorted(THRESHOLDS)}")
    out = dict(THRESHOLDS)
    for key, value in thresholds.items():
        out[key] = positive_float(f"thresholds[{key!r}]", value,
                                  upper=1.0 if key == "correlation" else None)
    return out


def closest_pair(model: Model, params: np.ndarray) -> tuple[float, tuple[int, int]]:
    """The two closest sources of ``params`` (P,): their distance and indices (i < j).

    Distances as :func:`olsbayes.resolution.source_distances` gives them (ring and
    sphere: angle in rad; plate: Euclidean); the first such pair in the order of
    :func:`~olsbayes.antipodal.source_pairs` on ties.  ``(inf, (-1, -1))`` for fewer
    than two sources.
    """
    params = finite_array("params", params, ndim=1)
    k = model.n_sources_of(params)
    if k < 2:
        return np.inf, (-1, -1)
    d = source_distances(model, params[None, :])[0]
    q = int(np.argmin(d))
    i, j = source_pairs(k)
    return float(d[q]), (int(i[q]), int(j[q]))


def laplace_trust(
    model: Model,
    params: np.ndarray,
    fisher: np.ndarray,
    *,
    thresholds: Mapping[str, float] | None = None,
) -> tuple[tuple[str, ...], dict[str, float]]:
    """Reasons not to trust the Laplace evidence at an ML point (empty: trusted).

    Parameters
    ----------
    model : Model
    params : ndarray, shape (P,)
        ML point.
    fisher : ndarray, shape (P, P)
        Fisher matrix at ``params``.
    thresholds : mapping, optional
        Overrides of :data:`THRESHOLDS` (unknown keys are refused).

    Returns
    -------
    reasons : tuple of str
    stats : dict
        ``separation`` (sensor spacings), ``min_snr``, ``max_correlation``,
        ``condition`` (of the correlation matrix) -- NaN where not defined.
    """
    th = check_thresholds(thresholds)
    k = model.n_sources_of(params)
    reasons: list[str] = []
    stats = {"separation": np.inf, "min_snr": np.inf, "max_correlation": 0.0, "condition": 1.0}
    if k == 0:
        return (), stats
    cov, _, singular = bound_covariance(fisher)
    if singular.any():
        names = [n for n, s in zip(model.param_names(k), singular) if s]
        reasons.append(f"singular Fisher matrix ({', '.join(names)} unidentifiable)")
        stats.update(min_snr=np.nan, max_correlation=1.0, condition=np.inf)
    else:
        sd = np.sqrt(np.diag(cov))
        corr = cov / np.outer(sd, sd)
        off = np.abs(corr - np.eye(len(sd)))
        stats["max_correlation"] = float(off.max()) if len(sd) > 1 else 0.0
        w = np.linalg.eigvalsh(corr)
        stats["condition"] = float(w.max() / w.min()) if w.min() > 0 else np.inf
        if stats["max_correlation"] > th["correlation"]:
            i, j = np.unravel_index(np.argmax(off), off.shape)
            nm = model.param_names(k)
            reasons.append(
                f"ill-conditioned Fisher matrix (corr({nm[i]}, {nm[j]}) = {corr[i, j]:+.3f})"
            )
        inten = np.asarray(params, float).reshape(k, -1)[:, -1]
        snr = inten / sd.reshape(k, -1)[:, -1]
        stats["min_snr"] = float(snr.min())
        if snr.min() < th["snr"]:
            q = int(np.argmin(snr))
            reasons.append(f"weak source I[{q}] = {inten[q]:.3g} ({snr[q]:.1f} sd above 0)")
    sep, (i, j) = closest_pair(model, params)
    if np.isfinite(sep):
        sep_h = sep / sensor_spacing(model)
        stats["separation"] = sep_h
        if sep_h < th["separation"]:
            reasons.append(
                f"sources {i} and {j} {sep_h:.2f} sensor spacings apart "
                f"(< {th['separation']:g}: near the resolution limit)"
            )
    return tuple(reasons), stats
