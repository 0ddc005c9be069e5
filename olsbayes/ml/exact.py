"""Exact global maximum likelihood on a ring with the clipped cosine (a verifier).

On a ring the sub-sensor ``n`` at angle ``t_n`` reads ``sum_k I_k max(cos(a_k -
t_n), 0)``.  The 2N *crossing angles* ``t_n +- pi/2`` (a source on sub-sensor
n's horizon; coincident ones merged, e.g. ``t_n + pi/2 = t_m - pi/2`` on an
even ring) cut the circle into M arcs, each narrower than pi.  Inside arc ``j``
the set of sub-sensors that see a source is fixed (``V_nj``) and the reading is
*linear* in the source's phasor ``(x, y) = I (cos a, sin a)``:
``V_nj (x cos t_n + y sin t_n)``.  Each source is given one *state*:

* an arc ``j``: two linear parameters, columns ``V_j cos t`` and ``V_j sin t``,
  phasor restricted to the closed convex cone of the arc (pointed: width < pi);
* a crossing ``c`` (pinned): one parameter I >= 0, column ``max(cos(c - t), 0)``;
* absent (I = 0).

Claim.  The global minimum of chi^2 over all (angles, I >= 0) equals the least
linear least-squares residual over the configurations (sets of distinct states,
at most K) whose design matrix has full column rank and whose unique LS
solution is *feasible*: each arc phasor inside its closed cone, each pinned
intensity >= 0.

Proof.  ">=": a feasible configuration's solution is a parameter point, so its
residual is attained.  "<=": chi^2 is a convex quadratic on each cell (a
product of closed pointed polyhedral cones), bounded below, so it attains its
minimum there (Frank--Wolfe) and a global minimiser x* exists.  Let F be the
configuration holding x* in its relative interior (sources at I = 0 absent, on a
crossing pinned, else in an open arc).  x* minimises chi^2 on an open subset of
F's linear span, so its gradient vanishes there: x* is an unconstrained LS
solution of F.  If F has full rank, x* is its unique solution and F is
feasible.  Otherwise take d != 0 in the null space: chi^2 is constant on x* + s
d, and the line leaves F's closed set (a product of pointed cones holds no
line) at a relative-boundary point -- a global minimiser in a configuration of
lower dimension.  Induction on the dimension ends at a full-rank one.  Hence
rank-deficient configurations (two sources in one arc or on one crossing, an
arc with a pin on its end, neighbouring arcs, ...) can be skipped: exactly.

Numerics.  A configuration counts as rank-deficient when an LDL^T pivot of its
Gram matrix falls below :data:`RANK_RTOL` times its diagonal entry (the squared
sine between a column and the span of the earlier ones): structurally singular
configurations give <~1e-12, full-rank ones >~1e-4 (measured on rings of 3..64
sub-sensors, all configurations up to K = 3).  The normal equations rank
configurations only to ~eps cond(G) |s|^2 in chi^2, so the near-best ones are
re-solved by ``lstsq`` and scored by ``model.log_likelihood`` directly.

Cost.  sum_{a + q <= K} C(M, a) C(M, q) = sum_{k <= K} C(2M, k)
configurations of a arcs and q pins, M = N crossings on an even ring, 2N on an
odd one: Ring(30) K = 3 36k, K = 4 524k; Ring(31) K = 3 318k, K = 4 9.7M.  The
Gram blocks are look-ups in one table of the states' inner products, the LDL^T
factorisations are numpy-vectorised over chunks of configurations and shared by
all data vectors of a batch.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from .._validation import integer
from ..errors import InputError
from ..geometry import TWO_PI, Ring, wrap_angle
from ..model import Model
from ..scene import Scene
from ..sensitivity import Cosine, CosinePower

__all__ = ["ExactResult", "fit_exact", "crossing_angles", "MAX_SOURCES", "RANK_RTOL"]

#: Largest K accepted (K = 4 on an odd 31-ring: ~9.7M configurations, ~13 s).
MAX_SOURCES = 4
#: Relative LDL^T pivot below which a configuration counts as rank-deficient.
RANK_RTOL = 1e-10
#: Relative slack of the feasibility tests (cone sides, pinned I >= 0).
FEAS_RTOL = 1e-12
#: Gains b^T G^-1 b within this times s.s of the best are re-ranked directly.
RERANK_RTOL = 1e-10
#: Near-best configurations kept per data vector for the direct re-ranking.
_MAX_CANDIDATES = 64
#: Merge tolerance (rad) of coincident crossing angles.
MERGE_TOL = 1e-9
#: Configurations x data vectors x parameters per chunk (~16 MiB of float64).
_CHUNK_TERMS = 1 << 21


@dataclass(frozen=True, eq=False)
class ExactResult:
    """Global ML estimate(s) of a ring with the clipped cosine.

    Attributes
    ----------
    params : ndarray, shape (P,) or (T, P)
        Estimate in the model's flat layout ``[angle, I]`` per source, canonical
        order; sources the optimum does not need are ``[0, 0]``.
    log_likelihood : ndarray, shape () or (T,)
        Gaussian log-likelihood at ``params`` (``model.log_likelihood``).
    n_configurations : int
        Configurations enumerated (per data vector).
    n_feasible : ndarray of int, shape () or (T,)
        Full-rank configurations whose LS solution is feasible.
    n_sources : int
        Number K of sources fitted.
    model : Model
        The model fitted.
    """

    params: np.ndarray
    log_likelihood: np.ndarray
    n_configurations: int
    n_feasible: np.ndarray
    n_sources: int
    model: Model = field(repr=False)

    def __post_init__(self) -> None:
        for name in ("params", "log_likelihood", "n_feasible"):
            arr = np.array(getattr(self, name))
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    @property
    def is_batch(self) -> bool:
        """True for a batch fit (leading trial axis)."""
        return self.params.ndim == 2

    @property
    def scene(self) -> Scene:
        """The estimated scene of a single fit."""
        if self.is_batch:
            raise InputError("scene is defined for a single fit; this result is a batch")
        return self.model.unpack(self.params)


def crossing_angles(ring: Ring) -> np.ndarray:
    """Distinct horizon-crossing angles ``t_n +- pi/2`` (rad), ascending in [0, 2 pi).

    Parameters
    ----------
    ring : Ring
        The array.

    Returns
    -------
    ndarray, shape (M,)
        M = N on an even ring (crossings coincide in pairs), 2N on an odd one.
    """
    t = np.asarray(ring.angles)
    c = np.sort(np.mod(np.concatenate([t + np.pi / 2, t - np.pi / 2]), TWO_PI))
    keep = np.concatenate([[True], np.diff(c) > MERGE_TOL])
    c = c[keep]
    if c.size > 1 and c[-1] - c[0] > TWO_PI - MERGE_TOL:
        c = c[:-1]
    return c


def _design(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Crossings c (M,) and state columns B (N, 3M): arc j at 2j, 2j+1, pin j at 2M + j.

    Arc j runs counter-clockwise from c[j] to c[j + 1] (cyclic).
    """
    c = crossing_angles(model.array)
    t = np.asarray(model.array.angles)
    width = np.diff(np.append(c, c[0] + TWO_PI))
    vis = (np.cos((c + width / 2)[None, :] - t[:, None]) > 0).astype(float)  # (N, M)
    cols = np.empty((t.size, 3 * c.size))
    cols[:, 0 : 2 * c.size : 2] = vis * np.cos(t)[:, None]
    cols[:, 1 : 2 * c.size : 2] = vis * np.sin(t)[:, None]
    pin = np.cos(c[None, :] - t[:, None])
    cols[:, 2 * c.size :] = np.where(pin > 1e-12, pin, 0.0)  # horizon sensors read 0
    return c, cols


def _check(model: object, data: object, n_sources: object) -> tuple[np.ndarray, int]:
    """Validated data (T, N) and K; InputError for anything but a ring with the cosine."""
    from .api import _check as check_ml

    if isinstance(model, Model) and not isinstance(model.array, Ring):
        raise InputError(
            "model.array must be a Ring (fit_exact enumerates a ring's horizon "
            f"cells); got {type(model.array).__name__}")
    law = getattr(model, "sensitivity", None)
    if isinstance(model, Model) and not (
            type(law) is Cosine or (type(law) is CosinePower and law.p == 1.0)):
        raise InputError(
            "model.sensitivity must be the clipped cosine (Cosine, 'cosine'); "
            f"got {law!r}")
    arr, k = check_ml(model, data, n_sources, "fast")
    k = integer("n_sources", k, low=1, high=MAX_SOURCES)
    return (arr if arr.ndim == 2 else arr[None, :]), k


def _combinations(n: int, r: int) -> np.ndarray:
    """All r-subsets of range(n) as rows, shape (C(n, r), r), int64."""
    if r == 0:
        return np.zeros((1, 0), dtype=np.int64)
    flat = itertools.chain.from_iterable(itertools.combinations(range(n), r))
    return np.fromiter(flat, dtype=np.int64).reshape(-1, r)


def _ldl(g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched LDL^T of Gram matrices with a rank test.

    Parameters
    ----------
    g : ndarray, shape (C, p, p)
        Symmetric positive semi-definite matrices.

    Returns
    -------
    low : ndarray, shape (C, p, p)
        Unit lower-triangular factors (strict lower part used).
    piv : ndarray, shape (C, p)
        Pivots D (set to 1 where rank-deficient).
    ok : ndarray of bool, shape (C,)
        Full rank: every pivot above :data:`RANK_RTOL` times its diagonal entry.
    """
    n, p = g.shape[:2]
    low = np.zeros_like(g)
    piv = np.empty((n, p))
    ok = np.ones(n, dtype=bool)
    for j in range(p):
        w = low[:, j, :j] * piv[:, :j]  # L_jk D_k
        dj = g[:, j, j] - np.einsum("ck,ck->c", w, low[:, j, :j])
        bad = dj <= RANK_RTOL * g[:, j, j]
        ok &= ~bad
        piv[:, j] = np.where(bad, 1.0, dj)
        if j + 1 < p:
            num = g[:, j + 1 :, j] - np.einsum("cik,ck->ci", low[:, j + 1 :, :j], w)
            low[:, j + 1 :, j] = num / piv[:, j, None]
    return low, piv, ok


def _solve(low: np.ndarray, piv: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LS solutions x (T, C, p) and explained sums b^T G^-1 b (T, C) for b (T, C, p)."""
    p = piv.shape[1]
    z = np.empty_like(b)
    for i in range(p):
        z[..., i] = b[..., i] - np.einsum("ck,tck->tc", low[:, i, :i], z[..., :i])
    explained = np.einsum("tcp,tcp->tc", z * z, np.broadcast_to(1.0 / piv, z.shape))
    x = z / piv
    for i in range(p - 2, -1, -1):
        x[..., i] -= np.einsum("ck,tck->tc", low[:, i + 1 :, i], x[..., i + 1 :])
    return x, explained


def _feasible(x: np.ndarray, arcs: np.ndarray, units: np.ndarray) -> np.ndarray:
    """Whether each LS solution x (T, C, p) lies in its cell; arcs (C, a) arc indices."""
    a = arcs.shape[1]
    scale = FEAS_RTOL * np.max(np.abs(x), axis=-1, initial=0.0)  # (T, C)
    ok = np.all(x[..., 2 * a :] >= -scale[..., None], axis=-1)
    m = units.shape[0]
    for r in range(a):
        px, py = x[..., 2 * r], x[..., 2 * r + 1]
        u0, u1 = units[arcs[:, r]], units[(arcs[:, r] + 1) % m]
        ok &= u0[:, 0] * py - u0[:, 1] * px >= -scale
        ok &= px * u1[:, 1] - py * u1[:, 0] >= -scale
    return ok


@dataclass
class _Best:
    """Running best configurations per data vector (internal, mutable).

    ``cands[t]`` holds every feasible (gain, arcs, pins) within ``margin[t]`` of
    the best gain b^T G^-1 b (chi^2 = s.s - gain): the normal equations rank
    configurations only to ~eps cond(G) s.s, so near-ties are re-ranked on
    direct residuals at the end.
    """

    gain: np.ndarray  # (T,)
    margin: np.ndarray  # (T,)
    cands: list  # (T,) lists of (gain, arcs, pins)
    n_feasible: np.ndarray  # (T,)

    def offer(self, t: int, gain: np.ndarray, arcs: np.ndarray, pins: np.ndarray) -> None:
        """Add trial t's feasible configurations (gains (C,)) that are near-best."""
        top = max(self.gain[t], float(gain.max(initial=-np.inf)))
        if top > self.gain[t]:
            self.gain[t] = top
            self.cands[t] = [c for c in self.cands[t] if c[0] >= top - self.margin[t]]
        for i in np.flatnonzero(gain >= top - self.margin[t]):
            self.cands[t].append((gain[i], arcs[i], pins[i]))
        if len(self.cands[t]) > _MAX_CANDIDATES:  # e.g. all-zero data: everything ties
            self.cands[t].sort(key=lambda cand: -cand[0])
            del self.cands[t][_MAX_CANDIDATES:]


def _scan_group(gram: np.ndarray, b: np.ndarray, best: _Best, units: np.ndarray,
                a: int, q: int) -> int:
    """Enumerate the configurations of a arcs and q pins, offer them to ``best``.

    gram (3M, 3M) and b (T, 3M): the states' Gram table and A^T s; units (M, 2)
    the crossing directions.  Returns the number of configurations.
    """
    m = units.shape[0]
    arc_sets, pin_sets = _combinations(m, a), _combinations(m, q)
    n_total, n_pin = arc_sets.shape[0] * pin_sets.shape[0], pin_sets.shape[0]
    p, n_t = 2 * a + q, b.shape[0]
    step = max(64, _CHUNK_TERMS // (p * max(p, n_t)))
    for start in range(0, n_total, step):
        flat = np.arange(start, min(start + step, n_total))
        arcs, pins = arc_sets[flat // n_pin], pin_sets[flat % n_pin]
        idx = np.concatenate([np.stack([2 * arcs, 2 * arcs + 1], -1).reshape(len(flat), 2 * a),
                              2 * m + pins], axis=1)
        low, piv, ok = _ldl(gram[idx[:, :, None], idx[:, None, :]])
        arcs, pins, idx, low, piv = arcs[ok], pins[ok], idx[ok], low[ok], piv[ok]
        x, gain = _solve(low, piv, b[:, idx])
        feas = _feasible(x, arcs, units)
        best.n_feasible += feas.sum(axis=1)
        for t in range(n_t):
            best.offer(t, gain[t, feas[t]], arcs[feas[t]], pins[feas[t]])
    return n_total


def _best_params(model: Model, c: np.ndarray, cols: np.ndarray, s: np.ndarray,
                 cands: list, k: int) -> np.ndarray:
    """Flat parameters (2K,) of the candidate with the largest direct log L.

    Each candidate's LS problem is re-solved by ``lstsq`` (no squared condition
    number) and scored with ``model.log_likelihood`` on the data vector s (N,).
    """
    best_x, best_ll = np.zeros(2 * k), float(model.log_likelihood(np.zeros(2 * k), s))
    m = c.size
    for _, arcs, pins in cands:
        idx = np.concatenate([np.stack([2 * arcs, 2 * arcs + 1], -1).ravel(), 2 * m + pins])
        sol = np.linalg.lstsq(cols[:, idx], s, rcond=None)[0]
        x = _params(c, arcs, pins, sol, k)
        ll = float(model.log_likelihood(x, s))
        if ll > best_ll:
            best_x, best_ll = x, ll
    return best_x


def _params(c: np.ndarray, arcs: np.ndarray, pins: np.ndarray, x: np.ndarray,
            k: int) -> np.ndarray:
    """Flat parameters (2K,) of a configuration's solution; absent sources [0, 0]."""
    out = np.zeros((k, 2))
    width = np.diff(np.append(c, c[0] + TWO_PI))
    for r, j in enumerate(arcs):
        px, py = x[2 * r], x[2 * r + 1]
        off = np.mod(np.arctan2(py, px) - c[j], TWO_PI)
        if off > width[j]:  # within the feasibility slack outside: nearest end
            off = 0.0 if off > width[j] + 0.5 * (TWO_PI - width[j]) else width[j]
        out[r] = c[j] + off, np.hypot(px, py)
    for i, j in enumerate(pins):
        out[len(arcs) + i] = c[j], max(x[2 * len(arcs) + i], 0.0)
    out[:, 0] = wrap_angle(out[:, 0])
    return out.ravel()


def fit_exact(model: Model, data: np.ndarray, n_sources: int) -> ExactResult:
    """Global maximum-likelihood fit of a ring with the clipped cosine, by enumeration.

    Exact up to rounding (see the module docstring for the argument): every
    configuration of at most K sources in distinct arcs / on distinct crossings
    is solved by linear least squares, and the best feasible one is returned.

    Parameters
    ----------
    model : Model
        A :class:`~olsbayes.Ring` model with the clipped cosine law.
    data : array_like, shape (N,) or (T, N)
        Readings; a batch shares the data-independent factorisations.
    n_sources : int
        Number K of sources, 1 <= K <= :data:`MAX_SOURCES` (and 2K <= N).
        The cost grows like (2M)^K / K! configurations (M crossings): K = 3
        on a 30-ring 36k (~30 ms), K = 4 524k (~0.7 s), K = 4 on an odd
        31-ring 9.7M (~13 s per data vector).

    Returns
    -------
    ExactResult
        Canonical-order global optimum and its log-likelihood.

    Raises
    ------
    InputError
        A model other than a ring with the clipped cosine, bad data or n_sources.
    """
    s, k = _check(model, data, n_sources)
    c, cols = _design(model)
    n_t = s.shape[0]
    gram, b = cols.T @ cols, s @ cols  # (3M, 3M), (T, 3M)
    margin = RERANK_RTOL * np.einsum("tn,tn->t", s, s)
    best = _Best(gain=np.zeros(n_t), margin=margin, cands=[[] for _ in range(n_t)],
                 n_feasible=np.ones(n_t, dtype=np.int64))
    units = np.column_stack([np.cos(c), np.sin(c)])
    n_conf = 1  # the empty configuration (all sources absent)
    for a in range(k + 1):
        for q in range(1 if a == 0 else 0, k - a + 1):
            n_conf += _scan_group(gram, b, best, units, a, q)
    x = np.array([_best_params(model, c, cols, s[t], best.cands[t], k) for t in range(n_t)])
    x = model.canonical(x)
    ll = model.log_likelihood(x, s)
    batch = np.ndim(data) == 2
    sel = (lambda v: v) if batch else (lambda v: v[0])
    return ExactResult(params=sel(x), log_likelihood=sel(ll), n_configurations=n_conf,
                       n_feasible=sel(best.n_feasible), n_sources=k, model=model)
