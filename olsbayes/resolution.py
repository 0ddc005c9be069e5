r"""Where Gaussian (Fisher) uncertainties stop describing the posterior.

An ML fit's errors -- the inverse Fisher matrix, the CRLB at the estimate --
and the Laplace evidence built on them describe the posterior when it is one
Gaussian mode well inside the prior.  Simulation-based calibration over
separation and SNR (``analyses/calibration_map.py``) shows where it is not:

* two sources closer than about 1.5 sensor spacings (``2 pi / N`` on a ring):
  within one linear cell of the clipped cosine two sources add up to one
  cosine, the likelihood has flat valleys and rival optima along the pair, and
  Fisher intervals there cover the truth far less often than stated -- at one
  spacing and high SNR the 90 % intervals miss in most scenes, for K = 2, 3
  and 4 alike;
* a source whose intensity is less than three of its own standard deviations above zero
  (low SNR: the Gaussian reaches the prior's edge at 0 and the direction is
  barely localised), as for three sources two spacings apart at SNR 10;
* ring sources near antipodal (:mod:`olsbayes.antipodal`: the readings barely
  tell such a pair from its mirrored configuration): four sources or more with a
  pair within one sensor spacing of antipodal, or two such pairs at once -- where
  Fisher intervals covered the truth less often than stated (far less for two
  pairs).  A single such pair among two or three sources under-covers only a
  little and is not flagged.

:func:`gaussian_doubts` finds these conditions at a batch of estimates from the
estimates and their covariances alone; :func:`warn_gaussian_doubts` turns them
into one :class:`~olsbayes.errors.NearResolutionWarning` naming what to use
instead: the posterior sampler for a weak source; for a pair below the
resolution limit, where at high SNR (10^4) one emcee ensemble under-covers too
(two sources 0.5-1 spacings apart), a model with one source fewer; and
``select_k(method="auto")`` for evidences;
:func:`olsbayes.ml.fit_ml` issues it.  Sources two or more spacings apart at
SNR 100 and above raise nothing.  Estimates without finite errors are left to
the singular-Fisher warning of the fit.
"""

from __future__ import annotations

import warnings

import numpy as np

from .antipodal import pair_offsets, source_pairs
from .circular import wrap_angle
from .errors import NearResolutionWarning
from .geometry import lonlat_to_unit

__all__ = ["gaussian_doubts", "warn_gaussian_doubts", "antipodal_doubts", "min_separation",
           "source_distances", "sensor_spacing", "weak_sources", "RESOLUTION_SPACINGS",
           "WEAK_SDS", "ANTIPODAL_DOUBT"]

#: Sources closer than this many sensor spacings are near the resolution limit.
RESOLUTION_SPACINGS = 1.5
#: A source whose intensity is below this many of its standard deviations is weak: its
#: 90 % Gaussian interval nearly reaches zero.
WEAK_SDS = 3.0
#: Ring source pairs nearer than this many sensor spacings to antipodal can be in doubt
#: (:func:`antipodal_doubts`).
ANTIPODAL_DOUBT = 1.0


#: What to do about a pair below the resolution limit (part of the warning).
CLOSE_ADVICE = (
    "at high SNR a single emcee ensemble (olsbayes.sample_posterior) did not cover the truth "
    "as often as stated either: the pair's centroid and summed intensity are determined, "
    "its separation is not, so compare one source fewer before reading per-source errors")


#: Sub-sensors above which each one's nearest neighbours come from a k-d tree
#: (:class:`scipy.spatial.cKDTree`, O(N log N)) rather than from a scan of every pair
#: (O(N^2), with no import: about 45 ms at this size and 0.3 s at N = 10,000).
_TREE_FROM = 2048
#: Candidates kept per sub-sensor: itself, its nearest neighbour and that one's ties
#: within rounding (up to six on a hexagonal lattice).
_CANDIDATES = 9
#: Floats in one block of rows of the pair scan (8 MiB): memory O(N) beyond it.
_BLOCK = 2**20


def sensor_spacing(model) -> float:
    """Typical distance between neighbouring sub-sensors, in source-location units.

    Angles (ring, sphere): the median angle (rad) between each normal and its
    nearest neighbour -- 2 pi / N on a uniform ring -- taken from the chord ``c``
    between the unit normals as ``2 arcsin(c / 2)``: a relative error of about
    eps / angle, where ``arccos`` of the dot product has eps / angle^2 (4e-12 against
    2e-8 on a ring of 100,000).  Positions (plate): the median nearest-neighbour
    distance of the sub-sensor positions.  Computed once per model (cached on it):
    over every pair up to 2048 sub-sensors, from a k-d tree's candidates beyond; O(N)
    memory.
    """
    return model.memo("sensor_spacing", lambda: _nearest_median(model))


def _nearest_median(model) -> float:
    far = model.kind != "position"
    pts = np.asarray(model.array.normals if far else model.array.positions, dtype=np.float64)
    nearest = _nearest_distances(pts)
    if far:  # pi for a lone sub-sensor (no neighbour: inf)
        nearest = _chord_angle(nearest)
    return float(np.median(nearest))


def _chord_angle(chord: np.ndarray) -> np.ndarray:
    """The angle (rad) between unit vectors a ``chord`` apart, ``2 arcsin(c / 2)``.

    Relative error about eps / angle, where ``arccos`` of their dot product has
    eps / angle^2; chords beyond 2 (inf) give pi.
    """
    return 2.0 * np.arcsin(np.minimum(0.5 * chord, 1.0))


def _nearest_distances(pts: np.ndarray) -> np.ndarray:
    """Euclidean distance from each point of ``pts`` (N, D) to its nearest other one (N,).

    The :data:`_CANDIDATES` nearest of each point, from a k-d tree above
    :data:`_TREE_FROM` points, else ranked by ``|q|^2 - 2 p.q`` over every pair (one
    matrix product per block of rows); then the distances to those candidates as
    ``|p - q|``, the same way for both, so either gives the all-pairs minimum of
    ``|p - q|`` to the bit.  inf for a lone point.
    """
    n, d = pts.shape
    width = min(n, _CANDIDATES)
    tree = None
    if n > _TREE_FROM:
        from scipy.spatial import cKDTree  # imported for large arrays only

        tree = cKDTree(pts)
    else:  # centred: the ranking's rounding is relative to the array's size
        centred = pts - pts.mean(axis=0)
        sq = np.einsum("ij,ij->i", centred, centred)
    out = np.empty(n)
    step = max(1, _BLOCK // max(width * d, n if tree is None else 1))
    for lo in range(0, n, step):
        rows = np.arange(lo, min(lo + step, n))
        if tree is None:
            key = sq - 2.0 * (centred[rows] @ centred.T)
            cand = np.argpartition(key, width - 1, axis=1)[:, :width]
        else:
            cand = tree.query(pts[rows], k=width)[1]
        dist = np.linalg.norm(pts[cand] - pts[rows, None, :], axis=-1)
        dist[cand == rows[:, None]] = np.inf
        out[rows] = dist.min(axis=1)
    return out


def source_distances(model, x: np.ndarray) -> np.ndarray:
    """Distance of each source pair of each row of ``x`` (T, P): (T, K (K - 1) / 2).

    Pairs in the order of :func:`~olsbayes.antipodal.source_pairs`.  Ring: the
    wrapped angle difference (rad); sphere: the great-circle angle (rad) from the
    chord between unit vectors, ``2 arcsin(c / 2)``, exact also for close pairs
    (``arccos`` of their dot product keeps half the digits); plate: the Euclidean
    distance (length units).
    """
    t, p = x.shape
    k = p // (model.n_loc + 1)
    loc = x.reshape(t, k, model.n_loc + 1)[..., :-1]
    i, j = source_pairs(k)
    if model.kind == "position":
        return np.linalg.norm(loc[:, i] - loc[:, j], axis=-1)
    if model.kind == "angle":
        theta = loc[..., 0]
        return np.abs(wrap_angle(theta[:, j] - theta[:, i]))
    u = lonlat_to_unit(loc[..., 0], loc[..., 1])
    return _chord_angle(np.linalg.norm(u[:, i] - u[:, j], axis=-1))


def min_separation(model, x: np.ndarray) -> np.ndarray:
    """Smallest source-to-source distance of each row of ``x`` (T, P), in sensor spacings.

    inf for rows of fewer than two sources (:func:`source_distances` of the pairs
    over :func:`sensor_spacing`).
    """
    if x.shape[1] // (model.n_loc + 1) < 2:
        return np.full(x.shape[0], np.inf)
    return source_distances(model, x).min(axis=1) / sensor_spacing(model)


def weak_sources(model, x: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Which sources of each row of ``x`` (T, P) are weak, bool (T, K).

    Weak: an intensity less than :data:`WEAK_SDS` of its sd, the square root of
    the diagonal of ``cov`` (T, P, P); an infinite or NaN sd (a singular Fisher
    matrix) counts as weak.
    """
    width = model.n_loc + 1
    var = np.diagonal(cov, axis1=-2, axis2=-1)[:, width - 1::width]
    with np.errstate(invalid="ignore"):
        return ~(x[:, width - 1::width] >= WEAK_SDS * np.sqrt(var))


def gaussian_doubts(model, x: np.ndarray, cov: np.ndarray) -> dict[str, np.ndarray]:
    """Which estimates sit where Gaussian errors are not calibrated.

    Parameters
    ----------
    model : Model
    x : ndarray (T, P)
        Estimates in the model's flat layout (K sources of ``model.n_loc + 1``).
    cov : ndarray (T, P, P)
        Their covariances (inverse Fisher matrices).

    Returns
    -------
    dict of bool ndarray (T,)
        ``close`` (two sources within :data:`RESOLUTION_SPACINGS` sensor
        spacings) and ``weak`` (an intensity below :data:`WEAK_SDS` of its sd),
        each only for rows whose errors are all finite; and ``separation``
        (float (T,), the smallest separation in sensor spacings).
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    cov = np.asarray(cov, dtype=float).reshape(x.shape[0], x.shape[1], x.shape[1])
    var = np.diagonal(cov, axis1=-2, axis2=-1)
    finite = np.all(np.isfinite(cov), axis=(1, 2)) & np.all(var > 0, axis=1)
    weak = weak_sources(model, x, cov).any(axis=1)
    sep = min_separation(model, x)
    return {"close": finite & (sep < RESOLUTION_SPACINGS), "weak": finite & weak,
            "separation": sep}


def antipodal_doubts(model, x: np.ndarray) -> np.ndarray:
    """Which ring estimates have near-antipodal pairs whose Fisher errors are not calibrated.

    Parameters
    ----------
    model : Model
        Other kinds than a ring (``kind == "angle"``) have no such pairs.
    x : ndarray (T, P)
        Estimates in the model's flat layout.

    Returns
    -------
    ndarray of bool (T,)
        Rows with four sources or more and a pair within :data:`ANTIPODAL_DOUBT`
        sensor spacings of antipodal, or with two such pairs.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    t, p = x.shape
    k = p // (model.n_loc + 1)
    if model.kind != "angle" or k < 2:
        return np.zeros(t, dtype=bool)
    # each pair's offset from antipodal, as olsbayes.antipodal.antipodal_pairs measures it
    near = np.abs(pair_offsets(model, x)) < ANTIPODAL_DOUBT  # (T, pairs)
    if k >= 4:
        return near.any(axis=1)
    return np.count_nonzero(near, axis=1) >= 2


def warn_gaussian_doubts(model, x: np.ndarray, cov: np.ndarray, method: str, *,
                         stacklevel: int = 2, doubt: dict[str, np.ndarray] | None = None
                         ) -> None:
    """One :class:`~olsbayes.errors.NearResolutionWarning` for fits in :func:`gaussian_doubts`.

    ``x`` (T, P) and ``cov`` (T, P, P) of a batch of ``method`` fits; nothing is
    issued when no row is in doubt.  ``doubt``: their :func:`gaussian_doubts`, if
    the caller has it already.
    """
    doubt = gaussian_doubts(model, x, cov) if doubt is None else doubt
    bad = doubt["close"] | doubt["weak"]
    if not bad.any():
        return
    what = []
    if doubt["close"].any():
        sep = np.floor(100 * float(np.min(doubt["separation"][doubt["close"]]))) / 100
        what.append(f"two sources {sep:.2f} sensor spacings apart (below "
                    f"{RESOLUTION_SPACINGS:g}: the resolution limit)")
    if doubt["weak"].any():
        what.append(f"a source intensity less than {WEAK_SDS:g} sd above zero")
    advice = (CLOSE_ADVICE if doubt["close"].any() else
              "sample the posterior (olsbayes.sample_posterior) for uncertainties")
    warnings.warn(
        f"{int(bad.sum())} of {bad.size} ML fit(s) ({method}) have {'; '.join(what)}: "
        "there the posterior is not one Gaussian (flat valleys, rival optima, a bound at "
        "zero) and in simulation the Fisher (CRLB) intervals covered the truth far less "
        f"often than stated; {advice}; use select_k(method='auto') rather than Laplace "
        "evidences",
        NearResolutionWarning,
        stacklevel=stacklevel + 1,
    )
