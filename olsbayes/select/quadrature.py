"""Evidence of one or two ring sources by quadrature (known sigma, box intensities).

On a ring with Gaussian noise of known sd the readings are linear in the
intensities, ``y = G(theta) I + noise``.  For fixed directions the likelihood
is Gaussian in ``I`` with mean ``I_hat = A^-1 G^T y`` and covariance
``S = sigma^2 A^-1`` (``A = G^T G``), so the box prior Uniform(lo, hi)^K of the
intensities integrates exactly::

    int L dI / (hi - lo)^K = (2 pi sigma^2)^(-N/2) exp(-|y - G I_hat|^2 / 2 sigma^2)
                             (2 pi)^(K/2) sqrt(det S) P(lo <= X <= hi) / (hi - lo)^K,

``X ~ N(I_hat, S)``: a normal CDF difference for K = 1, a bivariate-normal
rectangle probability (Owen's T function) for K = 2.  What is left, the
integral over the directions on the circle or the torus (uniform prior density
``(2 pi)^-K``, labelled sources: the full torus, no K! factor), is done on a
two-level grid: coarse cells are screened by the unconstrained best fit at
their centre (an upper bound of the likelihood over the intensities) with a
slack for the likelihood's curvature across a cell, the kept cells are split
into fine cells of about one posterior width (from the ML fits' Fisher
information), or, where those exceed the budget, of about one local width per
direction (:mod:`olsbayes.select.cells`), fine cells within ``margin`` nats of
the best are kept, and each gets ``per_cell`` uniform draws (more where the
error is above 2 %).  The stratified estimate of Z, each cell's mean weighted
by its area, carries its own standard error; cells dropped by the screen hold
less than ``e^-margin`` of the best cell's mass each.

Two nearly coincident directions make ``A`` nearly singular: ``|y|^2 - y^T G
I_hat`` then loses its digits (at sigma = 1e-4 it can exceed the best fit's
log-likelihood by thousands of nats), so the misfit is taken from the residual
itself there; and the rectangle probability, far in an elongated Gaussian's
tail, is bounded by its smaller marginal instead of by the CDFs' rounding.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..priors import CircularUniform, ScenePrior, Uniform
from .cells import _CHUNK, _MAX_CELLS, projection_gain, screen, unit_responses

__all__ = ["QuadratureEvidence", "qualifies", "box_log_prob", "ring_log_evidence",
           "unit_responses", "projection_gain"]

#: Stated standard error (nats) above which the quadrature value is not used.
MAX_ERROR = 0.1
_MARGIN = 25.0      # nats below the best cell from which fine cells are dropped
_PER_CELL = 2       # uniform draws per fine cell (>= 2 for the within-cell variance)
_TARGET = 0.02      # relative error beyond which the cells get more draws (within budget)
_TAIL = 1e-10       # box probabilities below which the marginal bound replaces the CDFs'
_ILL = 1e-6         # det(Gram) / (a c) below which the misfit comes from the residual


@dataclass(frozen=True)
class QuadratureEvidence:
    """log Z of 1 or 2 ring sources by quadrature.

    Attributes
    ----------
    log_evidence : float
        log Z (nats); NaN when the grid would exceed its budget (``why``).
    error : float
        Standard error of log Z (nats): the stratified sampling error of the
        direction integral plus the rounding of the box probabilities.
    n_cells : int
        Fine cells kept (each with ``per_cell`` draws).
    n_grid : int
        Fine cells per direction on the full circle.
    seconds : float
        Wall time, s.
    why : str
        Empty, or why no value was computed.
    """

    log_evidence: float
    error: float
    n_cells: int
    n_grid: int
    seconds: float
    why: str = ""

    def __repr__(self) -> str:
        return (f"QuadratureEvidence(log_evidence={self.log_evidence:.4f}, "
                f"error={self.error:.2g}, n_cells={self.n_cells}, n_grid={self.n_grid})")


def qualifies(model, prior: object) -> bool:
    """Whether :func:`ring_log_evidence` integrates this model and scene prior exactly.

    A ring with Gaussian noise of known sd and no nuisance terms, K = 1 or 2,
    uniform directions on the circle and intensities Uniform(lo, hi).
    """
    from ..measurement import is_plain

    return bool(
        model.kind == "angle" and is_plain(model) and isinstance(prior, ScenePrior)
        and prior.n_sources in (1, 2) and prior.noise is None and not prior.extra
        and isinstance(prior.location[0], CircularUniform)
        and isinstance(prior.intensity, Uniform))


def _log_interval(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """log(Phi(hi) - Phi(lo)) for lo <= hi, accurate in both tails."""
    from scipy.special import log_ndtr  # on use: scipy is slow to import
    upper = lo > 0  # both in the upper tail: use the reflection
    a, b = np.where(upper, -hi, lo), np.where(upper, -lo, hi)
    la, lb = log_ndtr(a), log_ndtr(b)
    with np.errstate(divide="ignore"):
        return lb + np.log1p(-np.exp(np.minimum(la - lb, 0.0)))


def _bvn(h: np.ndarray, k: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """P(X1 <= h, X2 <= k) of standard normals with correlation rho (|rho| < 1).

    Owen (1956): Phi2 = (Phi(h) + Phi(k)) / 2 - T(h, a_h) - T(k, a_k) - beta,
    ``a_h = (k - rho h) / (h s)``, ``a_k = (h - rho k) / (k s)``, ``s = sqrt(1 - rho^2)``,
    beta = 1/2 when h k < 0 (or one is 0 and h + k < 0).
    """
    from scipy.special import ndtr, owens_t  # on use: scipy is slow to import
    h = np.where(h == 0, 1e-300, h)
    k = np.where(k == 0, 1e-300, k)
    s = np.sqrt((1 - rho) * (1 + rho))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a_h, a_k = (k - rho * h) / (h * s), (h - rho * k) / (k * s)
    beta = np.where(h * k < 0, 0.5, 0.0)
    out = 0.5 * (ndtr(h) + ndtr(k)) - owens_t(h, a_h) - owens_t(k, a_k) - beta
    return np.clip(out, 0.0, 1.0)


def box_log_prob(mean: np.ndarray, cov: np.ndarray, lo: float, hi: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """log P(lo <= X <= hi) for X ~ N(mean, cov) in K = 1 or 2 dimensions.

    Parameters
    ----------
    mean : ndarray, shape (n, K)
    cov : ndarray, shape (n, K, K)
        Positive definite.
    lo, hi : float
        The box [lo, hi]^K.

    Returns
    -------
    log_p : ndarray, shape (n,)
    abs_err : ndarray, shape (n,)
        Bound on the absolute rounding error of P (0 for K = 1, whose log is
        accurate to rounding in both tails; the four bivariate CDFs of K = 2,
        each accurate to ~1e-15, after reflecting each coordinate so that the
        box lies on the side of the mean's lower tail).  Where the smaller
        marginal probability ``P_m`` of K = 2 is below ``_TAIL`` (1e-10), P and
        its value both lie in [0, P_m]: the value is capped at P_m and the
        bound is ``min(P_m, 4e-15)``.
    """
    mean, cov = np.asarray(mean, float), np.asarray(cov, float)
    if mean.ndim != 2 or mean.shape[1] not in (1, 2) or cov.shape != mean.shape + mean.shape[1:]:
        raise InputError(f"mean must have shape (n, 1|2) and cov (n, K, K); got "
                         f"{mean.shape} and {cov.shape}")
    sd = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    low, high = (lo - mean) / sd, (hi - mean) / sd
    if mean.shape[1] == 1:
        return _log_interval(low[:, 0], high[:, 0]), np.zeros(len(mean))
    rho = np.clip(cov[:, 0, 1] / (sd[:, 0] * sd[:, 1]), -1 + 1e-15, 1 - 1e-15)
    # the smaller marginal probability bounds P; below _TAIL it bounds the value and its
    # error better than the CDFs' rounding (a box far in the tail of an elongated Gaussian)
    log_m = np.min(_log_interval(low, high), axis=1)
    tail = log_m < math.log(_TAIL)
    flip = low + high > 0  # mean below the box's centre: reflect so the box is in a lower tail
    low, high = np.where(flip, -high, low), np.where(flip, -low, high)
    rho = np.where(flip[:, 0] != flip[:, 1], -rho, rho)
    p = (_bvn(high[:, 0], high[:, 1], rho) - _bvn(low[:, 0], high[:, 1], rho)
         - _bvn(high[:, 0], low[:, 1], rho) + _bvn(low[:, 0], low[:, 1], rho))
    with np.errstate(divide="ignore"):
        log_p = np.log(np.maximum(p, 0.0))
    return (np.where(tail, np.minimum(log_p, log_m), log_p),
            np.where(tail, np.minimum(np.exp(log_m), 4e-15), 4e-15))


def _log_integrand(model, data: np.ndarray, theta: np.ndarray, lo: float, hi: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """log of int L(theta, I) p(I) dI at directions ``theta`` (n, K), and its rounding.

    Returns ``(log_f, log_err)``: ``exp(log_err)`` (n,) bounds the absolute error
    of ``exp(log_f)`` from the box probability's rounding.  Directions
    whose Gram matrix is singular to rounding (coincident sources, a null set)
    get ``-inf``.
    """
    n, k = theta.shape
    s2 = model.sigma**2
    g = unit_responses(model, theta.ravel()).reshape(n, k, -1)  # (n, K, N)
    gram = np.einsum("nis,njs->nij", g, g)
    rhs = g @ data  # (n, K)
    diag = np.diagonal(gram, axis1=1, axis2=2)
    det = np.linalg.det(gram) if k == 2 else diag[:, 0]
    ok = det > (1e-11 * np.prod(diag, axis=1) if k == 2 else 0.0)
    gram = np.where(ok[:, None, None], gram, np.eye(k))
    inv = np.linalg.inv(gram)
    i_hat = np.einsum("nij,nj->ni", inv, rhs)
    misfit = data @ data - np.einsum("ni,ni->n", i_hat, rhs)
    ill = ok & (det < _ILL * np.prod(diag, axis=1))  # never for K = 1 (det = a)
    if np.any(ill):  # |y|^2 - gain has lost its digits there: the residual itself
        res = data - np.einsum("ni,nis->ns", i_hat[ill], g[ill])
        misfit[ill] = np.einsum("ns,ns->n", res, res)
    log_rest = (-0.5 * len(data) * math.log(2 * math.pi * s2) - 0.5 * misfit / s2
                + 0.5 * k * math.log(2 * math.pi * s2) - 0.5 * np.log(np.where(ok, det, 1.0))
                - k * math.log(hi - lo))
    log_p, abs_err = box_log_prob(i_hat, s2 * inv, lo, hi)
    with np.errstate(divide="ignore"):
        return (np.where(ok, log_rest + log_p, -np.inf),
                np.where(ok & (abs_err > 0), log_rest + np.log(abs_err), -np.inf))


def _narrowest_width(model, fits: list[np.ndarray]) -> float:
    """1 / sqrt(largest curvature of log L in the directions) over the ML fits (rad).

    The largest eigenvalue of the direction block of the Fisher information
    bounds the curvature of the profile likelihood (intensities at their best).
    """
    lam = 0.0
    for x in fits:
        x = np.asarray(x, float)
        with np.errstate(all="ignore"):
            f = model.fisher(x)[0::2, 0::2]
        if np.all(np.isfinite(f)) and f.size:
            lam = max(lam, float(np.max(np.linalg.eigvalsh(f))))
    return 1.0 / math.sqrt(lam) if lam > 0 else math.nan


def ring_log_evidence(model, data: np.ndarray, prior: ScenePrior, fits: list[np.ndarray], *,
                      rng: np.random.Generator, margin: float = _MARGIN,
                      per_cell: int = _PER_CELL) -> QuadratureEvidence:
    """log Z of K = 1 or 2 ring sources under ``prior``, by quadrature (see module notes).

    Parameters
    ----------
    model : Model
        A plain ring model (:func:`qualifies`).
    data : ndarray, shape (N,)
    prior : ScenePrior
        Uniform directions, intensities Uniform(lo, hi), sigma known.
    fits : list of ndarray
        ML parameter vectors (the K fit, and smaller K) whose Fisher information
        sets the narrowest posterior width, so the fine cells' size.
    rng : Generator
        The uniform draws in the cells.
    margin : float
        Fine cells more than ``margin`` nats below the best are dropped (> 0).
    per_cell : int
        Draws per fine cell (>= 2); every cell gets more, pooled with these, when
        the relative error exceeds ``_TARGET`` (2 %) and the budget allows.

    Returns
    -------
    QuadratureEvidence
        NaN with ``why`` when no width is defined or the grid exceeds the budget.
    """
    t0 = time.perf_counter()
    data, k = _check(model, data, prior, margin, per_cell), prior.n_sources
    sd = _narrowest_width(model, fits)
    found = ("no finite Fisher information at the ML fits" if not sd > 0
             else screen(model, data, k, sd, margin, prior.intensity.lo))
    if isinstance(found, str):
        return QuadratureEvidence(math.nan, math.nan, 0, 0, time.perf_counter() - t0, found)
    cells, lo, hi = found, prior.intensity.lo, prior.intensity.hi

    def draws(m: int) -> tuple[np.ndarray, np.ndarray]:
        theta = cells.draw(m, rng)
        parts = [_log_integrand(model, data, theta[i:i + _CHUNK], lo, hi)
                 for i in range(0, len(theta), _CHUNK)]  # bounded memory per pass
        return tuple(np.concatenate(v).reshape(len(cells.index), m) for v in zip(*parts))

    log_f, log_err = draws(per_cell)
    if not np.any(np.isfinite(log_f)):  # every draw on coincident directions (a null set)
        return QuadratureEvidence(math.nan, math.nan, len(cells.index), cells.n_grid,
                                  time.perf_counter() - t0, "no draw off the diagonal")
    rel_area, log_area = cells.log_area()
    rel = _stratified(log_f, log_err, rel_area)[1]
    more = math.ceil(per_cell * min(rel / _TARGET, 1e3) ** 2) - per_cell
    if more > 0 and len(cells.index) * (per_cell + more) <= _MAX_CELLS:
        extra = draws(more)  # pooled with the first draws
        log_f, log_err = (np.concatenate([a, b], axis=1) for a, b in zip((log_f, log_err),
                                                                          extra))
    log_total, rel = _stratified(log_f, log_err, rel_area)
    return QuadratureEvidence(float(log_total + log_area), rel, len(cells.index), cells.n_grid,
                              time.perf_counter() - t0)


def _check(model, data: object, prior: object, margin: object, per_cell: object) -> np.ndarray:
    """The readings (N,) as floats, after checking every argument of ring_log_evidence."""
    if not qualifies(model, prior):
        raise InputError(f"ring_log_evidence needs a plain ring model and a scene prior of "
                         f"1 or 2 sources with uniform directions and Uniform intensities; "
                         f"got {prior!r}")
    if not (isinstance(margin, (int, float)) and margin > 0
            and isinstance(per_cell, (int, np.integer)) and per_cell >= 2):
        raise InputError(f"margin must be > 0 and per_cell an integer >= 2; got {margin!r}, "
                         f"{per_cell!r}")
    data = np.asarray(data, dtype=float)
    if data.shape != (model.n_sensors,) or not np.all(np.isfinite(data)):
        raise InputError(f"data must be {model.n_sensors} finite readings; got shape "
                         f"{data.shape}")
    return data


def _stratified(log_f: np.ndarray, log_err: np.ndarray, area: np.ndarray) -> tuple[float, float]:
    """log of the area-weighted sum over cells of the in-cell mean of f (M, m), relative error.

    ``area`` (M,): each cell's area relative to a reference.  The error: the
    stratified sampling error (within-cell variances) plus the box
    probabilities' rounding.
    """
    top = float(np.max(log_f))
    f, m = np.exp(log_f - top), log_f.shape[1]
    total = float(np.sum(f.mean(axis=1) * area))
    var = float(np.sum(f.var(axis=1, ddof=1) * area**2) / m)
    rounding = float(np.sum(np.exp(log_err - top) * area[:, None])) / m
    return top + math.log(total), (math.sqrt(var) + rounding) / total
