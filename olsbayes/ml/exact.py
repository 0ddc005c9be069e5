"""Exact global maximum likelihood on a ring with the clipped cosine, by enumeration.

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
re-solved through a QR factorisation of their columns and scored by
``model.log_likelihood`` directly.  Where several configurations give the same
likelihood to rounding (a scene the array cannot identify, e.g. K = 4 on a
16-ring), which of those equal optima is returned is a matter of rounding.

Cost.  sum_{a + q <= K} C(M, a) C(M, q) = sum_{k <= K} C(2M, k)
configurations of a arcs and q pins, M = N crossings on an even ring, 2N on an
odd one: Ring(30) K = 3 36k, K = 4 524k; Ring(31) K = 3 318k, K = 4 9.7M.  The
Gram matrices are look-ups in one table of the states' inner products; the scan
runs compiled (:mod:`olsbayes.ml._numba.exact`); the tests hold it against a
numpy reference vectorised over chunks of configurations.  Consecutive
configurations share their leading states, so the compiled scan refactors and
re-substitutes only the rows from the first changed state on, and a
configuration whose gain is already below the best so far is not
solved (unless feasible configurations are counted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._budget import check_memory
from .._notice import notice
from .._validation import integer
from ..circular import TWO_PI, wrap_angle
from ..errors import InputError
from ..geometry import Ring
from ..model import Model
from ..sensitivity import is_clipped_cosine

__all__ = ["ExactSolution", "check_exact", "check_design_memory", "enumerate_optimum",
           "crossing_angles", "n_configurations", "design_bytes", "MAX_SOURCES", "RANK_RTOL",
           "NOTICE_CONFIGURATIONS"]

#: Largest K accepted (K = 4 on an odd 31-ring: ~9.7M configurations).
MAX_SOURCES = 4
#: Relative LDL^T pivot below which a configuration counts as rank-deficient.
RANK_RTOL = 1e-10
#: Relative slack of the feasibility tests (cone sides, pinned I >= 0).
FEAS_RTOL = 1e-12
#: Gains b^T G^-1 b within this times s.s of the best are re-ranked directly.
RERANK_RTOL = 1e-10
#: Near-best configurations kept per data vector for the direct re-ranking.
_MAX_CANDIDATES = 64
#: Candidate configurations re-solved together (bounds the QR work arrays).
_RESOLVE_BLOCK = 8192
#: Merge tolerance (rad) of coincident crossing angles.
MERGE_TOL = 1e-9
#: Enumerations of more configurations than this (per call, all data vectors) say
#: so on stderr: about 1-2e7 configurations a second were measured on one core
#: (K = 3 on a 512-ring: 1.8e8 in 14 s).
NOTICE_CONFIGURATIONS = 50_000_000


@dataclass(frozen=True)
class ExactSolution:
    """Global optima of a batch of T data vectors (internal record).

    Attributes
    ----------
    params : ndarray, shape (T, P)
        Canonical-order optimum; sources the optimum does not need are ``[0, 0]``.
    log_likelihood : ndarray, shape (T,)
        Gaussian log-likelihood at ``params`` (``model.log_likelihood``).
    n_configurations : int
        Configurations enumerated (per data vector).
    n_feasible : ndarray of int, shape (T,), or None
        Full-rank configurations whose LS solution is feasible (counted on request).
    """

    params: np.ndarray
    log_likelihood: np.ndarray
    n_configurations: int
    n_feasible: np.ndarray | None


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


def n_configurations(model: Model, k: int) -> int:
    """Configurations the enumeration scans per data vector: sum_{j <= K} C(2M, j).

    M crossings (:func:`crossing_angles`): N on an even ring, 2N on an odd one.
    """
    m2 = 2 * crossing_angles(model.array).size
    return sum(math.comb(m2, j) for j in range(k + 1))


def design_bytes(model: Model) -> float:
    """Bytes of the enumeration's data-independent arrays (cached on the model).

    The state columns (N, 3M) and their Gram matrix (3M, 3M), doubles: O(N^2).
    """
    m3 = 3 * crossing_angles(model.array).size
    return 8.0 * (model.n_sensors * m3 + m3 * m3)


def _scan_design(model: Model) -> tuple[np.ndarray, ...]:
    """The scan's arrays of a model, cached on the model.

    :func:`_design` (c, cols), the states' Gram matrix cols' cols, the crossing
    directions (M, 2) and the arc widths (M,).

    Private and never written: writeable arrays, so that the compiled scan sees one
    array type whoever calls it.
    """
    def make() -> tuple[np.ndarray, ...]:
        c, cols = _design(model)
        return c, cols, cols.T @ cols, np.column_stack([np.cos(c), np.sin(c)]), _widths(c)

    return model.memo("exact_design", make)


def _design(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Crossings c (M,) and state columns B (N, 3M): arc j at 2j, 2j+1, pin j at 2M + j.

    Arc j runs counter-clockwise from c[j] to c[j + 1] (cyclic).
    """
    c = crossing_angles(model.array)
    t = np.asarray(model.array.angles)
    width = _widths(c)
    vis = (np.cos((c + width / 2)[None, :] - t[:, None]) > 0).astype(float)  # (N, M)
    cols = np.empty((t.size, 3 * c.size))
    cols[:, 0 : 2 * c.size : 2] = vis * np.cos(t)[:, None]
    cols[:, 1 : 2 * c.size : 2] = vis * np.sin(t)[:, None]
    pin = np.cos(c[None, :] - t[:, None])
    cols[:, 2 * c.size :] = np.where(pin > 1e-12, pin, 0.0)  # horizon sensors read 0
    return c, cols


def check_exact(model: Model, k: int) -> None:
    """Raise InputError unless the enumeration covers the model.

    Covered: a ring with the clipped cosine and 1 <= K <= :data:`MAX_SOURCES`.
    """
    if not isinstance(model.array, Ring):
        raise InputError(
            "method='exact' needs a Ring model (the enumeration of a ring's horizon "
            f"cells); got {type(model.array).__name__}")
    if not is_clipped_cosine(model.sensitivity):
        raise InputError(
            "method='exact' needs the clipped cosine law (Cosine, 'cosine'); got "
            f"{model.sensitivity!r}")
    integer("n_sources", k, low=1, high=MAX_SOURCES)
    check_design_memory(model, "method='exact'")


def check_design_memory(model: Model, what: str) -> None:
    """Refuse, before allocating, an enumeration whose O(N^2) arrays exceed the budget.

    ``what`` names the request in the message (``"method='exact'"``, ``"escalate=True"``).
    """
    check_memory(f"{what} on {model.n_sensors} sub-sensors (the enumeration's (N, 3M) "
                 "state columns and their Gram matrix)", design_bytes(model))


def _widths(c: np.ndarray) -> np.ndarray:
    """Widths (M,) of the arcs from crossing c[j] to c[j + 1] (cyclic), rad."""
    return np.diff(np.append(c, c[0] + TWO_PI))


def _best_params(model: Model, c: np.ndarray, width: np.ndarray, cols: np.ndarray,
                 s: np.ndarray, cstate: np.ndarray,
                 count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per data vector, its candidate with the largest direct log L, and that log L.

    Returns the canonical parameters (T, 2K) and the log L (T,); no source (all zeros)
    wins ties.

    ``cstate`` (T, C, K): candidate configurations (arc j -> j, pin j -> M + j,
    absent -> -1), the first ``count`` (T,) of each row.  Each LS problem is
    re-solved through a QR factorisation of its columns (no squared condition
    number), batched over the candidates of all vectors with the same numbers of
    arcs and pins, and scored with ``model.log_likelihood``.
    """
    n_t, n_c, k = cstate.shape
    rows, slot = np.nonzero(np.arange(n_c)[None, :] < count[:, None])
    states = cstate[rows, slot]  # (n, K)
    m = c.size
    group = np.sum((states >= 0) & (states < m), axis=1) * (k + 1) + np.sum(states >= m, axis=1)
    cand = np.zeros((n_t + states.shape[0], 2 * k))  # first n_t rows: no source
    for g in np.unique(group[group > 0]):
        sel = np.flatnonzero(group == g)
        a, q = divmod(int(g), k + 1)
        cand[n_t + sel] = _group_params(c, width, cols, s[rows[sel]], states[sel, :a],
                                        states[sel, a : a + q] - m, k)
    cand = model.canonical(cand)
    ll = np.full((n_t, n_c + 1), -np.inf)
    ll_all = model.log_likelihood(cand, s[np.concatenate([np.arange(n_t), rows])])
    ll[:, 0], ll[rows, slot + 1] = ll_all[:n_t], ll_all[n_t:]
    best = np.argmax(ll, axis=1)
    pick = np.where(best == 0, np.arange(n_t), n_t + np.searchsorted(rows, np.arange(n_t))
                    + best - 1)
    return cand[pick], ll[np.arange(n_t), best]


def _group_params(c: np.ndarray, width: np.ndarray, cols: np.ndarray, s: np.ndarray,
                  arcs: np.ndarray, pins: np.ndarray, k: int) -> np.ndarray:
    """Flat parameters (n, 2K) of n configurations of arcs and pins fitted to s (n, N).

    a arcs (n, a) and q pins (n, q); absent sources [0, 0].

    An arc phasor within the feasibility slack outside its arc goes to the
    nearest end.
    """
    m, a = c.size, arcs.shape[1]
    idx = np.concatenate([np.stack([2 * arcs, 2 * arcs + 1], -1).reshape(len(arcs), -1),
                          2 * m + pins], axis=1)  # (n, p)
    qm, rm = np.linalg.qr(np.swapaxes(cols.T[idx], 1, 2))  # (n, N, p), (n, p, p)
    sol = np.linalg.solve(rm, np.einsum("inp,in->ip", qm, s)[..., None])[..., 0]
    out = np.zeros((len(arcs), k, 2))
    width = width[arcs]  # (n, a)
    px, py = sol[:, 0 : 2 * a : 2], sol[:, 1 : 2 * a : 2]
    off = np.mod(np.arctan2(py, px) - c[arcs], TWO_PI)
    out_of_arc = off > width
    off = np.where(out_of_arc & (off > width + 0.5 * (TWO_PI - width)), 0.0,
                   np.where(out_of_arc, width, off))
    out[:, :a, 0], out[:, :a, 1] = c[arcs] + off, np.hypot(px, py)
    out[:, a : a + pins.shape[1], 0] = c[pins]
    out[:, a : a + pins.shape[1], 1] = np.maximum(sol[:, 2 * a :], 0.0)
    out[..., 0] = wrap_angle(out[..., 0])
    return out.reshape(len(arcs), 2 * k)


def enumerate_optimum(model: Model, data: np.ndarray, n_sources: int, *,
                      count_feasible: bool = False) -> ExactSolution:
    """Global maximum-likelihood fits of a ring with the clipped cosine, by enumeration.

    Exact up to rounding (see the module docstring for the argument): every
    configuration of at most K sources in distinct arcs / on distinct crossings
    is solved by linear least squares, and the best feasible one is returned.

    Parameters
    ----------
    model : Model
        A :class:`~olsbayes.Ring` model with the clipped cosine law
        (:func:`check_exact`).
    data : ndarray, shape (T, N)
        Validated readings; the batch shares the data-independent factorisations.
    n_sources : int
        Number K of sources, 1 <= K <= :data:`MAX_SOURCES` (and 2K <= N).  The cost
        grows like (2M)^K / K! configurations (M crossings): K = 3 on a 30-ring
        36k, K = 4 524k, K = 4 on an odd 31-ring 9.7M.
    count_feasible : bool
        Count the feasible configurations (``n_feasible``).  Without the count, the
        least-squares solution of every configuration that cannot be the optimum
        (its gain is below the best so far) is skipped: the same optimum, faster.

    Returns
    -------
    ExactSolution
    """
    from ._numba import exact  # numba is imported on first use, not with the package

    s = np.asarray(data, dtype=float)
    total = n_configurations(model, n_sources) * s.shape[0]
    if total > NOTICE_CONFIGURATIONS:
        notice(f"exact ML fit: enumerating {total:.3g} configurations of K = {n_sources} "
               f"sources (about 1-2e7 a second) ...")
    c, cols, gram, units, width = _scan_design(model)
    margin = RERANK_RTOL * np.einsum("tn,tn->t", s, s)
    _, cstate, count, n_feas, n_conf = exact.scan(
        gram, s @ cols, units, n_sources, margin, RANK_RTOL, FEAS_RTOL, _MAX_CANDIDATES,
        count_feasible)
    # candidates re-solved in blocks of rows: bounded memory when many configurations
    # tie (all-zero readings keep _MAX_CANDIDATES per row)
    step = max(1, _RESOLVE_BLOCK // _MAX_CANDIDATES)
    parts = [_best_params(model, c, width, cols, s[i : i + step], cstate[i : i + step],
                          count[i : i + step]) for i in range(0, s.shape[0], step)]
    x = np.concatenate([q[0] for q in parts])
    ll = np.concatenate([q[1] for q in parts])
    return ExactSolution(params=x, log_likelihood=ll, n_configurations=int(n_conf),
                         n_feasible=n_feas)
